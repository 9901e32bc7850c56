//! Fuzz target `check`: the input as a model file through `hybsim::fuzz::Target::Check`
//! (the body the seed-corpus test in tests/it/fuzz_corpus.rs runs on stable).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Err(v) = hybsim::fuzz::Target::Check.exercise(data) {
        panic!("{v}");
    }
});
