//! `radn denoise`: denoise an EXR sequence.

use std::path::PathBuf;

use anyhow::{anyhow, Result};
use radn_core::classic::pipeline::{ClassicDenoiser, ClassicParams};
use radn_core::denoiser::WindowDenoiser;
use radn_core::frame::Requirements;
use radn_core::passes::DenoiseRun;
use radn_core::sequence::{sequence_files, SequencePattern};
use radn_core::stabilize::{TemporalStabilizer, DEFAULT_STRENGTH as DEFAULT_STABILIZE_STRENGTH};
use radn_nn::infer::guide_mix::{MixGuide, DEFAULT_OUTLIER_RAMP};
use radn_nn::infer::input_blend::{BlendStrength, InputBlend};

use crate::input::{ChannelArgs, GuideArgs};
use radn_nn::device::ComputeDevice;

/// Denoising methods.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// The non-neural pipeline: flow-refined alignment, robust temporal average, joint NLM, guided filter.
    Classic,
    /// A kernel-predicting network: the shipped default Robust Average model, or --model.
    Network,
}

/// Storage type of denoised channels.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum Precision {
    /// Whatever the input channel uses.
    Same,
    /// 16-bit float.
    Half,
    /// 32-bit float.
    Float,
}

impl Precision {
    /// The sample kind to force, if any.
    pub fn kind(self) -> Option<radn_core::exr_file::SampleKind> {
        match self {
            Precision::Same => None,
            Precision::Half => Some(radn_core::exr_file::SampleKind::F16),
            Precision::Float => Some(radn_core::exr_file::SampleKind::F32),
        }
    }
}

/// Arguments of `radn denoise`.
#[derive(clap::Args)]
pub struct Args {
    /// Input sequence: a pattern (beauty.####.exr, beauty.%04d.exr, beauty.$F4.exr) or a folder.
    #[arg(short, long)]
    pub input: String,
    /// Output pattern (same frame-number syntax); every layer of the input is kept.
    #[arg(short, long)]
    pub output: String,
    /// Frames to denoise (first-last[xstep]); default: every frame found.
    #[arg(long)]
    pub frames: Option<String>,
    /// Denoising method.
    #[arg(long, value_enum, default_value = "network")]
    pub method: Method,
    /// Extra layers to denoise with the beauty's weights (comma-separated layer names, e.g. DiffCol,GlossCol).
    #[arg(long, value_delimiter = ',')]
    pub aovs: Vec<String>,
    /// Recompute frames whose output already exists (default: skip them, so a killed run resumes).
    #[arg(long)]
    pub overwrite: bool,
    /// Storage of the denoised channels: the input's own type, half or float.
    #[arg(long, value_enum, default_value = "same")]
    pub output_precision: Precision,
    /// Network: a model file (radn SafeTensors with its configuration embedded); default: the
    /// model compiled into radn (models/default.safetensors).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Network: kernel threshold t (paper eq. 3); higher keeps more of the input. Default: the model's.
    #[arg(long)]
    pub threshold: Option<f32>,
    /// Network: blend the result with the input per pixel by the Wiener gain of the change
    /// against the input's noise (the classic denoiser's guided blend), so that detail the
    /// noise does not explain is kept from the input. `auto` (also `--input-blend` alone):
    /// how many noise variances of change count as noise follows each frame's noise level
    /// (none at 4 spp, about 2 from 64 spp up); a number K: that many for every frame (larger
    /// keeps more of the network's result); `off`: the kernels' result as it is.
    #[arg(long, value_name = "auto|off|K", default_value = "auto", num_args = 0..=1,
          default_missing_value = "auto", value_parser = parse_input_blend)]
    pub input_blend: BlendChoice,
    /// Guided models: mix the result with a guide, (1 − W)·result + W·guide on the beauty
    /// (AOVs get the beauty's per-pixel gain, so they still sum to it); which guide: see
    /// --guide-mix-from and --guide-mix-range. The guide keeps detail the window's kernels
    /// average away; the kernels remove per-frame error the guide keeps. `auto`: the weight per
    /// pixel a model with a learned guide mix predicts; for other guided models 0.7 with the
    /// range term, 0.5 without it (each chosen on validation: docs/guided.md, "Guide mix" and
    /// "The window's guide with a range term"); nothing for others; `off` (or 0): the network's
    /// result alone; W: that weight everywhere (1: the guide alone).
    #[arg(long, value_name = "auto|off|W", default_value = "auto", value_parser = parse_guide_mix)]
    pub guide_mix: GuideMixChoice,
    /// With --guide-mix: which guide the result is mixed with. `centre`: the frame's own (its
    /// detail and its flicker); `window`: the window's aligned guides averaged by their
    /// confidence (less flicker, and less detail where the warps blur); `auto`: the window's for
    /// frames whose noise level the input blend leaves alone (4 and some 11-spp frames), the
    /// centre's for cleaner ones.
    #[arg(long, value_name = "auto|centre|window", default_value = "auto", value_parser = parse_mix_from)]
    pub guide_mix_from: MixGuide,
    /// Guided models: the window's guide in the mix takes a side frame's guide only where its
    /// luminance (mapped by x/(1+x)) is within about S of the centre frame's guide, by the
    /// weight exp(−(d/S)²) (a temporal bilateral filter). It averages a spatial denoiser's
    /// frame-to-frame error away and keeps the centre's own detail where a warp blurred or
    /// missed it, so the window's guide is then used at every level. S holds on the cleanest
    /// frames and loosens with the noise level (up to 4×); frames as noisy as 4 spp take the
    /// window's guide without it. `auto`: 0.02 for a guided model (chosen on six validation
    /// sets: docs/guided.md, "The window's guide with a range term"); `off`: the confidence
    /// alone, and --guide-mix-from decides.
    #[arg(long, value_name = "auto|off|S", default_value = "auto", value_parser = parse_mix_range)]
    pub guide_mix_range: MixRange,
    /// Guided models: where the result and its guide disagree far more than detail does
    /// (fireflies the kernels spread, pixels no sample lit that they keep dark), take the guide
    /// alone, pixel by pixel. `auto`: on for a guided model (a ramp over the difference of
    /// luminance mapped by x/(1+x), from 0.03 to 0.1), off for others; `off`: the mix's weight
    /// everywhere.
    #[arg(long, value_name = "auto|off", default_value = "auto", value_parser = parse_auto_off,
          action = clap::ArgAction::Set)]
    pub guide_mix_outliers: bool,
    /// Guided runs: alignment also compares each side frame's guide, warped, with the centre
    /// frame's, and lowers the side frame's confidence where they differ (a reflection or a
    /// refraction that moved over its surface, which motion vectors do not follow). `auto`: on
    /// for runs with a guide, at 0.6 (chosen on five validation sets: docs/guided.md, "Guide
    /// confidence"), off without one; `off`: the geometric terms alone; TOL: the relative
    /// difference of the 3×3-prefiltered guides at which the term is e^-1.
    #[arg(long, value_name = "auto|off|TOL", default_value = "auto", value_parser = parse_confidence_term)]
    pub guide_confidence: ConfidenceTerm,
    /// Network: alignment also compares each side frame's own colour (3×3 prefiltered), warped,
    /// with the centre frame's, and lowers its confidence where they differ: the unguided
    /// counterpart of --guide-confidence. TOL is the relative difference at which the term is
    /// e^-1 on the cleanest frames; it loosens with the frame's noise level (up to 4×) and is
    /// off for frames as noisy as 4 spp, whose colour is too noisy to compare. `auto`: 0.5 for
    /// runs without a guide (chosen on five validation sets: docs/guided.md, "Colour
    /// confidence"), off with one (the guide term does it better); `off`: the geometric terms
    /// alone.
    #[arg(long, value_name = "auto|off|TOL", default_value = "auto", value_parser = parse_confidence_term)]
    pub color_confidence: ConfidenceTerm,
    /// Network: the confidence terms that compare sampled buffers (albedo, normal and depth)
    /// loosen with the frame's noise level, up to K times: where a pixel covers fur, grass or
    /// foliage, a noisy frame's buffers differ from frame to frame by more than the strict
    /// tolerances allow, and the side frames would count for little (their flicker stays). The
    /// factor is the one the colour term loosens by (1 on the cleanest frames), at most K, and
    /// K for frames as noisy as 4 spp; the guide's term is kept. `auto`: 4 for runs with a
    /// guide (chosen on five validation sets: docs/guided.md, "Confidence on fur"), off
    /// without one (not measured); `off`: the strict tolerances at every level.
    #[arg(long, value_name = "auto|off|K", default_value = "auto", value_parser = crate::input::parse_loosening)]
    pub loosen_confidence: crate::input::Loosening,
    /// A temporal pass over the results, after the denoising passes: each frame's result
    /// averaged with its neighbours' results aligned onto it, each side frame by
    /// exp(−(d/σ)²) of its colour's distance from the centre's (display-mapped), where σ is A
    /// times the local RMS of the frame's render noise. It removes the frame-to-frame error
    /// that the window's motion vectors could not (fur, grass, through glass) and keeps what
    /// differs by more than the noise explains. AOVs and alpha get the beauty's weights, so
    /// they still sum. `auto`: 0.3 for a run with --guide (chosen on five validation sets:
    /// docs/guided.md, "A temporal pass over the results, with a range that follows the
    /// noise"), off for others; `off`: none. Costs a second decoding of each input and a
    /// scratch copy of each result; it runs whole frames (memory follows the frame).
    #[arg(long, value_name = "auto|off|A", default_value = "auto", value_parser = parse_stabilize)]
    pub stabilize: StabilizeChoice,
    /// Network: how alignment samples the side frames between pixels, `bilinear` or
    /// `catmull-rom` (keeps one-pixel detail through subpixel motion). Default: the way the
    /// model was trained (its description's `resampling`); another way feeds it windows it
    /// never saw.
    #[arg(long, value_enum)]
    pub resampling: Option<crate::input::ResamplingArg>,
    /// Network, with --input-blend: radius of the box the change and the noise are compared over.
    #[arg(long, default_value_t = 1)]
    pub input_blend_radius: usize,
    /// Network: output tile size in pixels (each tile gets a halo of the receptive field, so
    /// the result does not depend on it). Band by band (`--bands`), frames are also read,
    /// aligned and written in bands of this many rows; 0 processes whole frames.
    /// `auto`: the model's own choice, 256 for the default model and 512 for a narrow one such
    /// as guided-lean (whose tiles then recompute less halo).
    #[arg(long, default_value = "auto", value_parser = parse_tile)]
    pub tile: TileChoice,
    /// Network with tiles: whether frames are read, aligned, denoised and written band by band
    /// (a band is a row of tiles), so that memory follows the band, not the frame (about 1 GB
    /// at 1080p with the default model, growing with the width only). Whole frames are about
    /// 15% faster at 1080p and take memory in proportion to the frame (about 2 GB at 1080p).
    /// `auto`: band by band above 2.5 megapixels. The result is the same either way.
    #[arg(long, value_enum, default_value = "auto")]
    pub bands: crate::input::BandsArg,
    /// Network: tiles of equal size per network call. 1 is fastest on a CPU (measured in
    /// docs/benchmarks.md); larger batches hold that many tiles' activations at once.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub batch: u32,
    /// Network with a frame-local stem: run the stem in every window on the aligned frames, as
    /// training does, instead of once per frame with its features warped into the windows
    /// (slower; measures what warping features instead of inputs changes).
    #[arg(long)]
    pub stem_on_aligned_frames: bool,
    /// Network: run the network again on its own output this many times in all (widens the
    /// temporal reach, paper section 3).
    #[arg(long, default_value_t = 1)]
    pub passes: usize,
    /// Network: where it runs, cpu or cuda[:N] (a GPU; needs a build with the `cuda` feature,
    /// scripts/build-cuda). Alignment, reading and writing stay on the CPU.
    #[arg(long, default_value = "cpu", value_name = "cpu|cuda[:N]")]
    pub device: ComputeDevice,
    #[command(flatten)]
    pub guide: GuideArgs,
    #[command(flatten)]
    pub classic: ClassicArgs,
    #[command(flatten)]
    pub channels: ChannelArgs,
}

/// Options of the classic (non-neural) denoiser.
#[derive(clap::Args, Clone, Debug)]
pub struct ClassicArgs {
    /// Frames on each side of the centre (2 = the paper's 5-frame window).
    #[arg(long, default_value_t = 2)]
    pub radius: usize,
    /// Classic: NLM search radius in pixels.
    #[arg(long, default_value_t = 9)]
    pub search_radius: usize,
    /// Classic: NLM patch radius in pixels.
    #[arg(long, default_value_t = 3)]
    pub patch_radius: usize,
    /// Classic: NLM strength (larger removes more noise and more detail).
    #[arg(long, default_value_t = 0.45)]
    pub strength: f32,
    /// Classic: do not refine the renderer's motion with optical flow.
    #[arg(long)]
    pub no_refine: bool,
    /// Classic: skip the guided filter.
    #[arg(long)]
    pub no_guided: bool,
    /// Classic: take the guided filter's output everywhere, instead of only where the
    /// remaining noise explains what it changes (blurs clean inputs).
    #[arg(long)]
    pub fixed_guided: bool,
    /// Classic: how many noise variances of change the guided filter may make before its
    /// input is kept instead (1 = the Wiener gain; larger smooths more; 2 chosen on the detail validation scenes, docs/detail.md).
    #[arg(long, default_value_t = 2.0)]
    pub guided_noise_scale: f32,
    /// Classic: radius of the box the guided filter's change and the noise are compared over.
    #[arg(long, default_value_t = 1)]
    pub guided_blend_radius: usize,
    /// Classic: filter the beauty itself instead of beauty / albedo.
    #[arg(long)]
    pub no_demodulate: bool,
}

impl ClassicArgs {
    /// The classic denoiser these options describe.
    pub fn denoiser(&self) -> ClassicDenoiser {
        let mut p = ClassicParams::default();
        p.nlm.search_radius = self.search_radius;
        p.nlm.patch_radius = self.patch_radius;
        p.nlm.strength = self.strength;
        if self.no_refine {
            p.refine = None;
        }
        if self.no_guided {
            p.guided = None;
        }
        if self.fixed_guided {
            p.guided_blend = None;
        } else if let Some(b) = p.guided_blend.as_mut() {
            b.noise_scale = self.guided_noise_scale;
            b.radius = self.guided_blend_radius;
        }
        p.demodulate = !self.no_demodulate;
        ClassicDenoiser {
            params: p,
            radius: self.radius,
        }
    }
}

/// Denoises the sequence.
pub fn run(a: Args) -> Result<()> {
    let wanted = sequence_files(&a.input, a.frames.as_deref())?;
    let mut reader = a.channels.reader(&wanted[0].1, Requirements::DENOISE)?;
    reader.aovs = a.aovs.clone();
    let method: Box<dyn WindowDenoiser> = match a.method {
        Method::Classic if a.guide.guide.is_some() => {
            return Err(anyhow!(
                "--guide steers a guided network; the classic denoiser reads no guide"
            ))
        }
        Method::Classic if a.device.is_gpu() => {
            return Err(anyhow!(
                "--device {}: the classic denoiser runs on the CPU only; use --method network",
                a.device
            ))
        }
        Method::Classic => Box::new(a.classic.denoiser()),
        Method::Network => Box::new(network_from(&a)?),
    };
    if a.bands == crate::input::BandsArg::Always && method.banded().is_none() {
        tracing::warn!(
            "--bands always: this method runs whole frames (the classic method, --tile 0 or a \
             UNet), so memory follows the frame"
        );
    }
    let guided = a.method == Method::Network && a.guide.guide.is_some();
    let stabilize = match a.stabilize {
        StabilizeChoice::Auto => guided.then_some(DEFAULT_STABILIZE_STRENGTH),
        StabilizeChoice::Off => None,
        StabilizeChoice::Strength(s) => Some(s),
    }
    .map(TemporalStabilizer::new);
    let oidn = a.guide.apply(&mut reader)?;
    let run = DenoiseRun {
        input: SequencePattern::parse_or_folder(&a.input)?,
        output: SequencePattern::parse(&a.output)?,
        frames: wanted.iter().map(|(f, _)| *f).collect(),
        reader,
        overwrite: a.overwrite,
        output_kind: a.output_precision.kind(),
        passes: if a.method == Method::Network {
            a.passes.max(1)
        } else {
            1
        },
        oidn,
        bands: a.bands.into(),
        stabilize,
    };
    let t = std::time::Instant::now();
    let mut bar: Option<(usize, indicatif::ProgressBar)> = None;
    let report = run.run(method.as_ref(), |p| {
        if bar.as_ref().is_none_or(|(pass, _)| *pass != p.pass) {
            if let Some((_, pb)) = bar.take() {
                pb.finish_and_clear();
            }
            // the temporal pass, where there is one, comes after the denoising passes
            let label = if p.pass > run.passes {
                "temporal pass".to_string()
            } else {
                format!("pass {}/{}", p.pass, run.passes)
            };
            let pb = crate::progress::fine_frames(p.frames as u64, &label);
            bar = Some((p.pass, pb));
        }
        if let Some((_, pb)) = &bar {
            pb.set_position((p.done * crate::progress::PARTS_PER_FRAME as f64) as u64);
        }
    })?;
    if let Some((_, pb)) = bar {
        pb.finish_and_clear();
    }
    println!(
        "denoised {} frames ({} already done, skipped) in {:.1} s -> {}",
        report.written,
        report.skipped,
        t.elapsed().as_secs_f64(),
        a.output
    );
    if report.repaired > 0 {
        println!("repaired {} NaN/Inf input samples", report.repaired);
    }
    Ok(())
}

/// Loads the network method from the command-line options.
fn network_from(a: &Args) -> Result<radn_nn::infer::NetworkDenoiser> {
    let mut n = crate::model::network_for(a.model.as_deref(), &a.guide, a.device)?;
    if let Some(t) = a.threshold {
        let k = n.denoiser.config.kernel_taps() as f32;
        if !(0.0..1.0 / k).contains(&t) {
            return Err(anyhow!(
                "--threshold {t} must be in [0, 1/K) = [0, {:.5}) for this model",
                1.0 / k
            ));
        }
        n.threshold = t;
    }
    if let TileChoice(Some(tile)) = a.tile {
        n.tile = tile;
    }
    n.batch = a.batch as usize;
    n.warp_stem_features = !a.stem_on_aligned_frames;
    n.refine = a.input_blend.0.map(|strength| InputBlend {
        radius: a.input_blend_radius,
        strength,
    });
    let guided = n.denoiser.config.inputs.guide;
    n.guide_mix_from = a.guide_mix_from;
    n.guide_mix_range = match a.guide_mix_range {
        MixRange::Auto => guided.then_some(DEFAULT_GUIDE_MIX_RANGE),
        MixRange::Off => None,
        MixRange::Sigma(s) if !guided => {
            return Err(anyhow!(
                "--guide-mix-range {s} weighs the window's guides in a guided model's mix; this \
                 model reads no guide (run a guided model with --guide)"
            ))
        }
        MixRange::Sigma(s) => Some(s),
    };
    n.guide_mix = match a.guide_mix {
        GuideMixChoice::Auto if guided && n.guide_mix_range.is_some() => DEFAULT_RANGED_GUIDE_MIX,
        GuideMixChoice::Auto if guided => DEFAULT_GUIDE_MIX,
        GuideMixChoice::Auto => 0.0,
        GuideMixChoice::Weight(w) if w > 0.0 && !guided => {
            return Err(anyhow!(
                "--guide-mix {w} mixes a guided model's result with its guide; this model reads \
                 no guide (run a guided model with --guide)"
            ))
        }
        GuideMixChoice::Weight(w) => w,
    };
    // a number (or off) given on the command line replaces a learned mix
    n.guide_mix_learned = matches!(a.guide_mix, GuideMixChoice::Auto);
    n.guide_mix_outliers = (guided && a.guide_mix_outliers).then_some(DEFAULT_OUTLIER_RAMP);
    let with_guide = a.guide.guide.is_some();
    // `auto` keeps the terms crate::model::network_for set
    match a.guide_confidence {
        ConfidenceTerm::Auto => {}
        ConfidenceTerm::Tolerance(tol) if !with_guide => {
            return Err(anyhow!(
                "--guide-confidence {tol} compares the frames' guides; give them with --guide"
            ))
        }
        ConfidenceTerm::Tolerance(tol) => n.align.confidence.guide = Some(tol),
        ConfidenceTerm::Off => n.align.confidence.guide = None,
    }
    match a.color_confidence {
        ConfidenceTerm::Auto => {}
        ConfidenceTerm::Tolerance(tol) => n.color_confidence = Some(tol),
        ConfidenceTerm::Off => n.color_confidence = None,
    }
    n.loosen_sampled_terms = a.loosen_confidence.resolve(n.loosen_sampled_terms);
    if let Some(r) = a.resampling {
        n.align.resampling = r.into();
    }
    Ok(n)
}

/// `--tile`'s value: a size in pixels, `None` for `auto` (the model's own,
/// [`radn_nn::infer::auto_tile`]).
#[derive(Clone, Copy, Debug)]
pub struct TileChoice(pub Option<usize>);

/// Parses `--tile`: `auto` or a size in pixels (0: whole frames).
fn parse_tile(s: &str) -> Result<TileChoice, String> {
    if s == "auto" {
        return Ok(TileChoice(None));
    }
    s.parse::<usize>()
        .map(|t| TileChoice(Some(t)))
        .map_err(|_| format!("'{s}' is not auto or a tile size in pixels"))
}

/// `--input-blend`'s value: how the noise scale is chosen, `None` for `off`.
#[derive(Clone, Copy, Debug)]
pub struct BlendChoice(pub Option<BlendStrength>);

/// The guide mix `--guide-mix auto` gives a guided model without the range term
/// (`--guide-mix-range off`): chosen for the centre's guide on the detail validation scenes,
/// where 0.25, 0.5 and 0.75 were measured (docs/guided.md, "Guide mix").
pub const DEFAULT_GUIDE_MIX: f32 = 0.5;

/// The guide mix `--guide-mix auto` gives a guided model with the range term (the default):
/// chosen on six validation sets among 0.5, 0.6, 0.7, 0.8 and 1 (docs/guided.md, "The window's
/// guide with a range term"). 0.8 tied it; the lower weight keeps more of what the kernels do
/// for each AOV, whose share of the guide is only its share of the noisy pixel.
pub const DEFAULT_RANGED_GUIDE_MIX: f32 = 0.7;

/// `--guide-mix`'s value.
#[derive(Clone, Copy, Debug)]
pub enum GuideMixChoice {
    /// [`DEFAULT_GUIDE_MIX`] for a guided model, none for others.
    Auto,
    /// This weight of the guide (0: none).
    Weight(f32),
}

/// Parses `--guide-mix-from`.
fn parse_mix_from(s: &str) -> Result<MixGuide, String> {
    match s {
        "auto" => Ok(MixGuide::FollowLevel),
        "centre" | "center" => Ok(MixGuide::Centre),
        "window" => Ok(MixGuide::Window),
        _ => Err(format!("'{s}' is not auto, centre or window")),
    }
}

/// The window guide's range σ `--guide-mix-range auto` gives a guided model: chosen on six
/// validation sets among 0.01, 0.02 and 0.04 (docs/guided.md, "The window's guide with a range
/// term").
pub const DEFAULT_GUIDE_MIX_RANGE: f32 = 0.02;

/// `--guide-mix-range`'s value.
#[derive(Clone, Copy, Debug)]
pub enum MixRange {
    /// [`DEFAULT_GUIDE_MIX_RANGE`] for a guided model, none for others.
    Auto,
    /// No range term: the window's guide by confidence alone, where `--guide-mix-from` uses it.
    Off,
    /// This σ.
    Sigma(f32),
}

/// Parses `--guide-mix-range`: `auto`, `off` or a positive σ.
fn parse_mix_range(s: &str) -> Result<MixRange, String> {
    match s {
        "auto" => return Ok(MixRange::Auto),
        "off" => return Ok(MixRange::Off),
        _ => {}
    }
    match s.parse::<f32>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(MixRange::Sigma(v)),
        _ => Err(format!("'{s}' is not auto, off or a positive number")),
    }
}

/// `--stabilize`'s value.
#[derive(Clone, Copy, Debug)]
pub enum StabilizeChoice {
    /// The temporal pass with its default strength for a run with a guide, none for others.
    Auto,
    /// No temporal pass.
    Off,
    /// The temporal pass with this strength.
    Strength(f32),
}

/// Parses `--stabilize`: `auto`, `off` or a positive strength.
fn parse_stabilize(s: &str) -> Result<StabilizeChoice, String> {
    Ok(match parse_mix_range(s)? {
        MixRange::Auto => StabilizeChoice::Auto,
        MixRange::Off => StabilizeChoice::Off,
        MixRange::Sigma(v) => StabilizeChoice::Strength(v),
    })
}

/// Parses an `auto|off` switch: true for `auto`.
fn parse_auto_off(s: &str) -> Result<bool, String> {
    match s {
        "auto" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("'{s}' is not auto or off")),
    }
}

/// `--guide-confidence`'s and `--color-confidence`'s value.
#[derive(Clone, Copy, Debug)]
pub enum ConfidenceTerm {
    /// The term's default (`crate::model::network_for`): the guide term at
    /// `DEFAULT_GUIDE_CONFIDENCE` for runs with a guide, the colour term at
    /// `DEFAULT_COLOR_CONFIDENCE` for runs without one.
    Auto,
    /// The geometric terms alone.
    Off,
    /// The term at this tolerance.
    Tolerance(f32),
}

/// Parses `--guide-confidence` and `--color-confidence`: `auto`, `off` or a positive
/// tolerance.
fn parse_confidence_term(s: &str) -> Result<ConfidenceTerm, String> {
    match s {
        "auto" => Ok(ConfidenceTerm::Auto),
        "off" => Ok(ConfidenceTerm::Off),
        t => match t.parse::<f32>() {
            Ok(t) if t > 0.0 && t.is_finite() => Ok(ConfidenceTerm::Tolerance(t)),
            _ => Err(format!("'{t}' is not auto, off or a positive tolerance")),
        },
    }
}

/// Parses `--guide-mix`: `auto`, `off` or a weight in [0, 1].
fn parse_guide_mix(s: &str) -> Result<GuideMixChoice, String> {
    match s {
        "auto" => Ok(GuideMixChoice::Auto),
        "off" => Ok(GuideMixChoice::Weight(0.0)),
        w => match w.parse::<f32>() {
            Ok(w) if (0.0..=1.0).contains(&w) => Ok(GuideMixChoice::Weight(w)),
            _ => Err(format!("'{w}' is not auto, off or a weight in [0, 1]")),
        },
    }
}

/// Parses `--input-blend`: `auto`, `off` or a positive noise scale.
fn parse_input_blend(s: &str) -> Result<BlendChoice, String> {
    match s {
        "auto" => Ok(BlendChoice(Some(BlendStrength::FollowLevel))),
        "off" => Ok(BlendChoice(None)),
        k => match k.parse::<f32>() {
            Ok(k) if k.is_finite() && k > 0.0 => Ok(BlendChoice(Some(BlendStrength::Fixed(k)))),
            _ => Err(format!("'{k}' is not auto, off or a positive number")),
        },
    }
}
