//! A `radn` whose standard output is a pipe nobody reads any more (`radn inspect F | head`,
//! `grep -q`, a pager that quits) ends quietly, as Unix tools do: killed by SIGPIPE at its
//! first write, with no panic and no backtrace on stderr.
#![cfg(unix)]

mod common;

use std::os::unix::process::ExitStatusExt;
use std::process::{Command, Stdio};

/// Runs radn with stdout a pipe whose reading end is already closed.
fn with_closed_stdout(args: &[&str]) -> std::process::Output {
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    Command::new(env!("CARGO_BIN_EXE_radn"))
        .args(args)
        .stdout(writer)
        .stderr(Stdio::piped())
        .output()
        .unwrap()
}

#[test]
fn a_closed_pipe_ends_the_commands_that_print_quietly() {
    let frame = common::sample().join("low/frame_0004.exr");
    let reference = common::sample().join("ref");
    let frames = common::sample().join("half");
    for args in [
        vec!["inspect", frame.to_str().unwrap()],
        vec!["inspect", frame.to_str().unwrap(), "--json"],
        vec![
            "eval",
            "--result",
            frames.to_str().unwrap(),
            "--reference",
            reference.to_str().unwrap(),
        ],
    ] {
        let out = with_closed_stdout(&args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !stderr.contains("panicked") && !stderr.contains("Broken pipe"),
            "radn {}: {stderr}",
            args.join(" ")
        );
        assert_eq!(
            out.status.signal(),
            Some(libc::SIGPIPE),
            "radn {} should end by SIGPIPE: {:?} {stderr}",
            args.join(" "),
            out.status
        );
    }
    // the same command with a reader still works and prints
    let out = common::radn_ok(&["inspect", frame.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("ViewLayer.Combined.R"));
}
