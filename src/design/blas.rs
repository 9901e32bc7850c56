//! The BLAS/LAPACK threading of the design layer: one OpenBLAS thread, whatever the environment.
//!
//! Why: OpenBLAS's threaded and single-threaded code paths round differently (a threaded
//! `dpotrf`/`dgemm` splits its sums differently), so with `OPENBLAS_NUM_THREADS` left to the
//! machine a design's last digits followed the core count, and threaded BLAS called from rayon
//! workers oversubscribed the cores (each worker's BLAS call woke OpenBLAS's own pool: a
//! 0.2-s `check` took 30–50 s under contention). The design layer's parallelism is rayon's, over
//! blocks, with sums in a fixed order; BLAS runs on the calling thread. [`pin`] is called by
//! every entry point that may reach BLAS ([`super::lmi::Problem::solve`]) and by the `hybsim`
//! binary at start, before any BLAS call.

use std::sync::Once;

use std::ffi::c_int;

// OpenBLAS's own entry points (libopenblas, linked through `openblas-src`): not part of the
// reference BLAS API, so no binding crate declares them.
unsafe extern "C" {
    fn openblas_set_num_threads(num_threads: c_int);
    fn openblas_get_num_threads() -> c_int;
}

/// The number of threads OpenBLAS uses after [`pin`].
pub const BLAS_THREADS: usize = 1;

static PIN: Once = Once::new();

/// Sets OpenBLAS to [`BLAS_THREADS`] thread(s), once per process (later calls return at once).
/// Overrides `OPENBLAS_NUM_THREADS`, `OMP_NUM_THREADS` and the CPU count.
pub fn pin() {
    PIN.call_once(|| {
        // SAFETY: a plain setter of OpenBLAS's global thread count; `Once` makes the first call
        // happen before any design-layer BLAS call of this process and never concurrently with
        // another one.
        unsafe { openblas_set_num_threads(BLAS_THREADS as c_int) };
    });
}

/// The number of threads OpenBLAS uses (after [`pin`], which this calls; recorded in the
/// run's metadata).
pub fn threads() -> usize {
    pin();
    // SAFETY: a plain getter of OpenBLAS's global thread count.
    let n = unsafe { openblas_get_num_threads() };
    usize::try_from(n).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    #[test]
    fn pin_sets_one_thread() {
        super::pin();
        assert_eq!(super::threads(), super::BLAS_THREADS);
    }
}
