//! Fuzz target `run`: the input as a model file through `hybsim::fuzz::Target::Run`
//! (the body the seed-corpus test in tests/it/fuzz_corpus.rs runs on stable).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Err(v) = hybsim::fuzz::Target::Run.exercise(data) {
        panic!("{v}");
    }
});
