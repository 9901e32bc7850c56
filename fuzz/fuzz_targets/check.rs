//! Fuzz target `check`: the input (a model, `%%set` overrides, `%%table` files: `hybsim::fuzz::Input`)
//! through `hybsim::fuzz::Target::Check` (the body the seed-corpus test in tests/it/fuzz_corpus.rs
//! runs on stable; this file is that test's template, so it holds nothing else to lint).
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Err(v) = hybsim::fuzz::Target::Check.exercise(data) {
        panic!("{v}");
    }
});
