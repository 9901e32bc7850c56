//! The README's Rust property-test example ("Property tests"), compiled by
//! `cargo test` (which builds the examples) and run by `cargo run --example
//! readme_property_tests`; `tests/it/docs.rs` checks that the README shows
//! this code verbatim.

// Laid out as the README shows it.
#[rustfmt::skip]
fn main() -> Result<(), Box<dyn std::error::Error>> {
    // README begin
    use hybsim::engine::{models::BouncingBall, SimSettings};
    use hybsim::props::{run_tests, Dist, Outcome, Property, Scope, Subject, SystemSubject, TestConfig};

    let ball = SystemSubject::new(BouncingBall::new(9.81, 0.8), SimSettings::default().horizon_t(3.0),
                                  vec![Dist::Uniform { lo: 0.0, hi: 2.0 }, Dist::Fixed(0.0)])?;
    let props = [
        Property::always("above ground", |_, x| x[0] >= -1e-9),
        Property::nonincreasing("energy", Scope::Jumps, 0.0, |_, x| 0.5 * x[1] * x[1] + 9.81 * x[0]),
        Property::always("never above 1.5", |_, x| x[0] <= 1.5),        // false
    ];
    let report = run_tests(&ball, &props, &TestConfig::default().cases(200).seed(7));
    if let Outcome::Failed(cx) = &report.outcome {
        // shrunk to h(0) just above 1.5, failing at (t, j) = (0, 0)
        println!("{}", cx.describe(ball.inputs(), &ball.state_names()));
    }
    // README end
    assert!(matches!(report.outcome, Outcome::Failed(_)), "the false property must fail");
    Ok(())
}
