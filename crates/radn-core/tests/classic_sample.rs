//! The classic denoiser on the Cycles sample that ships in the repository, against its
//! 1024-spp reference (frames 3–7): quality gains at every noise level, and less flicker than
//! both the input and the same pipeline restricted to a single frame.

use std::path::PathBuf;

use radn_core::align::window_indices;
use radn_core::classic::pipeline::{denoise_window, refine_frame_motion, ClassicParams};
use radn_core::eval::metrics::{psnr, temporal};
use radn_core::io::frame::{Frame, FrameReader, Requirements};
use radn_core::io::mapping::ChannelMapping;
use radn_core::Plane;

const FRAMES: std::ops::RangeInclusive<i64> = 1..=9;
const EVAL: std::ops::RangeInclusive<i64> = 3..=7;

fn path(level: &str, f: i64) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(format!(
        "../../samples/cycles-sample/{level}/frame_{f:04}.exr"
    ))
}

fn read(level: &str, req: Requirements) -> Vec<Frame> {
    let r = FrameReader::new(ChannelMapping::builtin("cycles").unwrap(), req);
    FRAMES
        .filter(|f| level != "ref" || EVAL.contains(f))
        .map(|f| r.read(&path(level, f)).unwrap().0)
        .collect()
}

/// Denoises the evaluated frames with a window of the given radius.
fn denoise(frames: &[Frame], radius: usize, p: &ClassicParams) -> Vec<Plane> {
    let mut refined: Vec<Frame> = frames.to_vec();
    if let Some(rp) = &p.flow_refine {
        for (k, frame) in refined.iter_mut().enumerate() {
            let prev = k.checked_sub(1).map(|j| &frames[j]);
            refine_frame_motion(
                frame,
                prev,
                frames.get(k + 1),
                rp,
                p.align.invert_iterations,
            );
        }
    }
    EVAL.map(|f| {
        let pos = (f - FRAMES.start()) as usize;
        let window: Vec<Option<&Frame>> = window_indices(pos, frames.len(), radius)
            .iter()
            .map(|i| i.map(|i| &refined[i]))
            .collect();
        denoise_window(&window, p).color
    })
    .collect()
}

fn mean_psnr(x: &[Plane], r: &[Plane]) -> f64 {
    x.iter()
        .zip(r)
        .map(|(a, b)| psnr(a, b).unwrap())
        .sum::<f64>()
        / x.len() as f64
}

fn mean_tmae(x: &[Plane], r: &[Plane]) -> f64 {
    (1..x.len())
        .map(|i| temporal(&x[i - 1], &x[i], &r[i - 1], &r[i]).unwrap().0)
        .sum::<f64>()
        / (x.len() - 1) as f64
}

#[test]
fn classic_denoiser_beats_the_input_at_every_level_and_flickers_less() {
    let reference: Vec<Plane> = read("ref", Requirements::COLOR_ONLY)
        .into_iter()
        .map(|f| f.color)
        .collect();
    let p = ClassicParams::default();
    for (level, min_gain) in [("low", 4.0), ("half", 3.0), ("high", 2.0)] {
        let frames = read(level, Requirements::DENOISE);
        let noisy: Vec<Plane> = EVAL
            .map(|f| frames[(f - 1) as usize].color.clone())
            .collect();
        let out = denoise(&frames, 2, &p);
        let single = denoise(&frames, 0, &p);
        let (pn, po, ps) = (
            mean_psnr(&noisy, &reference),
            mean_psnr(&out, &reference),
            mean_psnr(&single, &reference),
        );
        let (tn, to, ts) = (
            mean_tmae(&noisy, &reference),
            mean_tmae(&out, &reference),
            mean_tmae(&single, &reference),
        );
        eprintln!("{level}: PSNR noisy {pn:.2} classic {po:.2} (1 frame {ps:.2}); tMAE noisy {tn:.5} classic {to:.5} (1 frame {ts:.5})");
        assert!(
            po - pn >= min_gain,
            "{level}: PSNR gain {:.2} dB < {min_gain}",
            po - pn
        );
        assert!(to < tn, "{level}: flicker did not drop vs the input");
        assert!(
            to < ts,
            "{level}: the 5-frame window flickers more than 1 frame"
        );
    }
}
