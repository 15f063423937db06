//! `radn`: temporal Monte Carlo denoising of rendered EXR sequences.

#![deny(missing_docs)]
// the arguments' doc comments are their help texts, where brackets are syntax (cuda[:N]),
// not links
#![allow(rustdoc::broken_intra_doc_links)]

mod cmd;
mod input;
mod model;
mod progress;

use clap::{Parser, Subcommand};

/// radn — a temporal Monte Carlo denoiser for rendered EXR sequences.
#[derive(Parser)]
#[command(name = "radn", version, about, long_about = None)]
struct Cli {
    /// Worker threads (default: all cores).
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// Log more (-v: debug, -vv: trace); RUST_LOG overrides.
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    /// Progress: bar, json (lines on stderr, for programs) or off.
    #[arg(
        long,
        global = true,
        value_enum,
        default_value_t,
        value_name = "STYLE",
        hide_possible_values = true
    )]
    progress: progress::Style,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Denoise an EXR sequence.
    Denoise(cmd::denoise::Args),
    /// Show an EXR's parts, channels, types, size and value statistics.
    Inspect(cmd::inspect::Args),
    /// Show a model file's network and recipe, or write a copy with its recipe tuned.
    Model(cmd::model::Args),
    /// Write the aligned (warped, confidence-weighted) window of one frame to an EXR.
    Warp(cmd::warp::Args),
    /// Compare a result sequence with a reference: PSNR, SSIM, relMSE, tMAE, tPSNR.
    Eval(cmd::eval::Args),
    /// Cut training tiles from rendered sequences at several noise levels.
    Prepare(cmd::prepare::Args),
    /// Train a network on prepared tiles.
    Train(cmd::train::Args),
    /// Make pseudo-references for a rendered dataset with the classic denoiser.
    Pseudoref(cmd::pseudoref::Args),
    /// Measure throughput: reading and warping a sequence, the classic denoiser (--classic),
    /// or a network's training steps and inference (--network).
    Bench(cmd::bench::Args),
}

/// Restores the default action of SIGPIPE, which the Rust runtime ignores: a `radn` whose
/// standard output is a pipe that closes (`radn inspect F | head`, `grep -q`, a pager that
/// quits) then ends quietly as every Unix tool does, instead of panicking on the failed write.
/// Files are never written through stdout, and outputs are renamed into place only when
/// complete, so ending there leaves no partial result.
fn end_quietly_on_broken_pipes() {
    #[cfg(unix)]
    // SAFETY: called first thing in main, before any thread exists; SIG_DFL is a valid action.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// Keeps freed large buffers in the process for reuse. glibc serves every allocation above its
/// mmap threshold (at most 32 MiB) with fresh pages from the kernel and returns them on free, so
/// each of the network's tile-sized activations (about 100 MB for a 256-pixel tile of five
/// frames) cost a page fault per 4 KiB: 76 s of system time of a 200 s 1080p frame
/// (docs/research/benchmarks.md, "Where the time goes"). With the thresholds raised, freed blocks are
/// reused; the peak resident memory stays that of the largest tile's working set.
fn reuse_large_allocations() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: called first thing in main, before any thread exists or anything is allocated
    // through these settings; mallopt only changes the allocator's thresholds.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, i32::MAX);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}

/// Ctrl-C and SIGTERM ask the run to stop at its next frame or band, which removes its
/// temporary files and claims as it unwinds (a host application cancels a run this way); a
/// second one ends the process at once, leaving debris that the next run on the folder removes.
fn stop_cleanly_on_interrupt() {
    let installed = ctrlc::set_handler(|| {
        if radn_core::run::cancel::requested() {
            std::process::exit(130);
        }
        radn_core::run::cancel::request();
        eprintln!("radn: stopping after the current band (again to stop at once)");
    });
    if let Err(e) = installed {
        tracing::warn!("Ctrl-C will stop radn at once, without cleaning up: {e}");
    }
}

fn main() -> std::process::ExitCode {
    end_quietly_on_broken_pipes();
    reuse_large_allocations();
    let cli = Cli::parse();
    progress::set_style(cli.progress);
    let level = match cli.verbose {
        0 => "info",
        1 => "debug",
        _ => "trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .init();
    if let Some(n) = cli.threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
        {
            eprintln!("error: cannot set {n} threads: {e}");
            return std::process::ExitCode::FAILURE;
        }
    }
    stop_cleanly_on_interrupt();
    let result = match cli.command {
        Command::Denoise(a) => cmd::denoise::run(a),
        Command::Inspect(a) => cmd::inspect::run(a),
        Command::Model(a) => cmd::model::run(a),
        Command::Warp(a) => cmd::warp::run(a),
        Command::Eval(a) => cmd::eval::run(a),
        Command::Bench(a) => cmd::bench::run(a),
        Command::Pseudoref(a) => cmd::pseudoref::run(a),
        Command::Prepare(a) => cmd::prepare::run(a),
        Command::Train(a) => cmd::train::run(a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) if is_cancelled(&e) => {
            eprintln!("error: {}", error_message(&e));
            std::process::ExitCode::from(130)
        }
        Err(e) => {
            eprintln!("error: {}", error_message(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// Whether the run ended because a stop was asked for (exit status 130, as for SIGINT).
fn is_cancelled(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        matches!(
            c.downcast_ref::<radn_core::Error>(),
            Some(radn_core::Error::Cancelled)
        )
    })
}

/// An error and its causes on one line, each cause once: the library's messages already
/// quote the I/O error they wrap, so a cause whose text the message holds is not repeated.
fn error_message(e: &anyhow::Error) -> String {
    let mut msg = e.to_string();
    for cause in e.chain().skip(1) {
        let text = cause.to_string();
        if !msg.contains(&text) {
            msg.push_str(": ");
            msg.push_str(&text);
        }
    }
    msg
}
