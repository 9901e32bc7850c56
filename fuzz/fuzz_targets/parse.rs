//! Fuzz target `parse`: the input as a model file through `hybsim::fuzz::Target::Parse`
//! (the body the seed-corpus test in tests/it/fuzz_corpus.rs runs on stable).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Err(v) = hybsim::fuzz::Target::Parse.exercise(data) {
        panic!("{v}");
    }
});
