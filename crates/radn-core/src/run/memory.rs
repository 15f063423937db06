//! Giving the heap's free memory back to the operating system between a run's phases.
//!
//! The `radn` binary keeps freed large blocks in the process for reuse (its `main` raises
//! glibc's mmap and trim thresholds), because the network's tile-sized activations would
//! otherwise fault in fresh pages for every tile. Band by band, a frame's OIDN guide (OIDN's
//! scratch of up to a gigabyte and the bands' images) and the network's bands take turns; the
//! blocks one phase frees do not fit the other's, so without a release between them the heap
//! holds both phases' peaks at once. [`release_free_memory`] hands the free pages back at such a
//! turn (between a guide's bands, too, whose last band differs in size); the next phase faults in
//! what it needs once.

/// Returns the free pages of the process's heap to the operating system (glibc's
/// `malloc_trim`): a no-op on other platforms and C libraries.
pub fn release_free_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        let started = std::time::Instant::now();
        // SAFETY: malloc_trim only walks glibc's own heaps and releases free pages; it is safe
        // to call from any thread at any time.
        unsafe {
            libc::malloc_trim(0);
        }
        crate::run::timing::add("releasing memory", started.elapsed());
    }
}
