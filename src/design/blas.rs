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
/// Overrides `OPENBLAS_NUM_THREADS`, `OMP_NUM_THREADS` and the CPU count, and stops the worker
/// threads OpenBLAS started when it was loaded (`stop_pool`).
pub fn pin() {
    PIN.call_once(|| {
        // SAFETY: a plain setter of OpenBLAS's global thread count; `Once` makes the first call
        // happen before any design-layer BLAS call of this process and never concurrently with
        // another one.
        unsafe { openblas_set_num_threads(BLAS_THREADS as c_int) };
        stop_pool();
    });
}

/// Stops the worker threads of a threaded OpenBLAS. It starts one per further CPU when the
/// library loads, and they spin on `sched_yield` until a timeout: with one BLAS thread they
/// never get work, yet a short run paid for their spinning (a third of the CPU time of a 10-ms
/// `hybsim run` that writes an MCAP file, whose `fsync` gave them time to spin). OpenBLAS's own
/// fork handler, `blas_thread_shutdown_`, joins them; OpenBLAS restarts its pool itself should a
/// later call want threads. Looked up at run time because OpenBLAS builds without threads (or
/// with OpenMP) do not have it.
fn stop_pool() {
    // SAFETY: `dlsym` with a NUL-terminated name in the process's global scope.
    let f = unsafe { libc::dlsym(libc::RTLD_DEFAULT, c"blas_thread_shutdown_".as_ptr()) };
    if f.is_null() {
        return;
    }
    // SAFETY: in OpenBLAS's pthread server the symbol is `int blas_thread_shutdown_(void)`; it
    // runs once, before any BLAS call of this process (see `pin`).
    let shutdown: unsafe extern "C" fn() -> c_int = unsafe { std::mem::transmute(f) };
    unsafe { shutdown() };
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

    /// After `pin` a threaded OpenBLAS has no worker threads left (`blas_server_avail` is its
    /// pool's flag), and BLAS still computes.
    #[test]
    fn pin_stops_the_worker_threads() {
        super::pin();
        // SAFETY: `dlsym` with a NUL-terminated name.
        let avail = unsafe { libc::dlsym(libc::RTLD_DEFAULT, c"blas_server_avail".as_ptr()) };
        if !avail.is_null() {
            // SAFETY: OpenBLAS's `int blas_server_avail`, read after `pin` returned.
            assert_eq!(unsafe { *(avail as *const std::ffi::c_int) }, 0);
        }
        let n: usize = 40;
        let mut a: Vec<f64> = (0..n * n)
            .map(|k| if k % (n + 1) == 0 { 4.0 } else { 0.0 })
            .collect();
        let mut info = 0;
        // SAFETY: `a` is an n×n column-major matrix.
        unsafe { lapack::dpotrf(b'L', n as i32, &mut a, n as i32, &mut info) };
        assert_eq!(info, 0);
        assert_eq!(a[0], 2.0);
    }
}
