//! The README's example of simulating a system defined in Rust ("Engine"),
//! compiled by `cargo test` (which builds the examples) and run by `cargo
//! run --example readme_rust_system`; `tests/it/docs.rs` checks that the
//! README shows this code verbatim.

// Laid out as the README shows it.
#[rustfmt::skip]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    // README begin
    use hybsim::engine::{models::BouncingBall, simulate_arc, SimRng, SimSettings};
    let arc = simulate_arc(&BouncingBall::new(9.81, 0.8), &[1.0, 0.0],
                           &SimSettings::default().horizon_t(5.0), &mut SimRng::seed_from(1))?;
    for jump in arc.jumps() { println!("{} at {}", arc.rule_name(jump.rule).unwrap(), jump.at); }
    // README end
    assert!(!arc.jumps().is_empty(), "the ball bounces within 5 s");
    Ok(())
}
