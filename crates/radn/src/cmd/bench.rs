//! `radn bench`: throughput of reading and aligning 5-frame windows on this machine.

use std::path::PathBuf;

use anyhow::{anyhow, Result};
use radn_core::eval::bench::time_windows;
use radn_core::io::frame::Requirements;
use radn_core::io::sequence::sequence_files;

use crate::input::ChannelArgs;

/// Arguments of `radn bench`.
#[derive(clap::Args)]
pub struct Args {
    /// Input sequence (pattern or folder) with at least 5 frames.
    #[arg(short, long, required_unless_present_any = ["network", "convs"])]
    pub input: Option<String>,
    /// Instead: time training steps of a network — a preset (small, paper, unet, tkpcn,
    /// spatial) or a TOML file — on one tile, next to a bare 3×3 conv stack of the same width
    /// and depth.
    #[arg(long)]
    pub network: Option<String>,
    /// Tile size for --network.
    #[arg(long, default_value_t = 128)]
    pub tile: usize,
    /// Tiles per training step (or per inference call) for --network.
    #[arg(long, default_value_t = 1)]
    pub batch: usize,
    /// With --network: time inference (what `radn denoise` runs per tile, no gradients)
    /// instead of training steps. A denoising tile is its output size plus twice the halo
    /// (348 for 256-pixel tiles of `small`).
    #[arg(long)]
    pub inference: bool,
    /// Repetitions (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub repeat: usize,
    /// Instead: time the 3×3 convolution shapes of the default network (input, residual
    /// blocks, RA predictor, kernel head) at inference on `--tile` maps of 5 frames, through
    /// radn's CPU path and through burn's, in GFLOP/s.
    #[arg(long, conflicts_with_all = ["network", "device"])]
    pub convs: bool,
    /// Instead: time Intel Open Image Denoise alone on the first frame of --input, on
    /// --device (its CUDA device for cuda): with the noisy auxiliaries, and prefiltered (the
    /// albedo and normal filters, then the beauty's: radn's guide), images in memory.
    #[arg(long, conflicts_with_all = ["network", "convs", "classic"])]
    pub oidn: bool,
    /// Instead: time radn's imported OIDN U-Nets (the standard noisy-auxiliary model and the
    /// large clean-auxiliary one) beside OIDN's own filter running the same weights, on the
    /// first frame of --input tiled to 1920×1080, filter time only, in one run.
    #[arg(long, conflicts_with_all = ["network", "convs", "classic", "oidn"])]
    pub unet: bool,
    /// For --network (training and --inference) and --oidn: where it runs, cpu or cuda[:N].
    #[arg(long, default_value = "cpu", value_name = "cpu|cuda[:N]")]
    pub device: radn_nn::device::ComputeDevice,
    /// Also time the classic denoiser's stages.
    #[arg(long)]
    pub classic: bool,
    #[command(flatten)]
    pub channels: ChannelArgs,
}

/// Times decoding and alignment (or a network); prints throughput.
pub fn run(a: Args) -> Result<()> {
    if a.convs {
        return convs(a.tile, a.repeat);
    }
    if let Some(preset) = &a.network {
        if a.inference {
            return inference(preset, a.tile, a.batch, a.repeat, a.device);
        }
        return network(preset, a.tile, a.batch, a.repeat, a.device);
    }
    let input = a
        .input
        .as_deref()
        .expect("clap requires --input without --network");
    let files = sequence_files(input, None)?;
    if files.len() < 5 {
        return Err(anyhow!(
            "'{input}' has {} frames; the benchmark needs 5",
            files.len()
        ));
    }
    let reader = a.channels.reader(&files[0].1, Requirements::DENOISE)?;
    if a.oidn {
        return oidn(&reader, &files[0].1, a.repeat, a.device);
    }
    if a.unet {
        return unet(&reader, &files[0].1, a.repeat);
    }
    let paths: Vec<PathBuf> = files[..5].iter().map(|(_, p)| p.clone()).collect();
    let t = time_windows(&reader, &paths, a.repeat, a.classic)?;
    let size = t.size;
    let mp = (size.0 * size.1) as f64 / 1e6;
    let (r, al) = (t.read, t.align);
    println!(
        "frame size {}x{} ({mp:.3} MP), {} threads, median of {}",
        size.0,
        size.1,
        rayon::current_num_threads(),
        a.repeat
    );
    println!(
        "read 5 frames:    {:8.1} ms   {:7.2} MP/s (frames decoded)",
        r * 1e3,
        5.0 * mp / r
    );
    println!(
        "align window:     {:8.1} ms   {:7.2} MP/s (centre pixels of 5-frame windows)",
        al * 1e3,
        mp / al
    );
    if let Some((rf, cl)) = t.classic {
        println!("classic refine:   {:8.1} ms   {:7.2} MP/s (TV-L1 towards both neighbours, once per frame)", rf * 1e3, mp / rf);
        println!("classic window:   {:8.1} ms   {:7.2} MP/s (align, temporal average, NLM, guided filter)", cl * 1e3, mp / cl);
        let total = r / 5.0 + rf + cl;
        println!(
            "classic per frame:{:8.1} ms   {:7.2} MP/s (decode + refine + window)",
            total * 1e3,
            mp / total
        );
    }
    Ok(())
}

/// A plane tiled (repeated) to `w × h`.
fn tiled(p: &radn_core::Plane, w: usize, h: usize) -> radn_core::Plane {
    radn_core::Plane::from_fn(w, h, p.channels(), |x, y, c| {
        p.get(x % p.width(), y % p.height(), c)
    })
}

/// The median of `repeats` timed runs of `f` after one warm-up.
fn median_secs(repeats: usize, mut f: impl FnMut() -> Result<()>) -> Result<f64> {
    let mut secs = Vec::new();
    for k in 0..=repeats.max(1) {
        let started = std::time::Instant::now();
        f()?;
        if k > 0 {
            secs.push(started.elapsed().as_secs_f64());
        }
    }
    secs.sort_by(f64::total_cmp);
    Ok(secs[secs.len() / 2])
}

/// Times radn's U-Net port beside OIDN's filter on the same 1080p frame and weights.
fn unet(
    reader: &radn_core::io::frame::FrameReader,
    path: &std::path::Path,
    repeats: usize,
) -> Result<()> {
    use radn_core::guide::{OidnDenoiser, OidnQuality};
    use radn_nn::oidn_unet::filter::{UnetFilter, UnetImages};
    let mut oidn = OidnDenoiser::new(0)?;
    let lib = radn_nn::oidn_unet::library::WeightsLibrary::open(oidn.library())?;
    let (f, _) = reader.read(path)?;
    let (w, h) = (1920, 1080);
    let albedo = f
        .albedo
        .as_ref()
        .ok_or_else(|| anyhow!("'{}' has no albedo", path.display()))?;
    let normal = f
        .normal
        .as_ref()
        .ok_or_else(|| anyhow!("'{}' has no normal", path.display()))?;
    let (c, a, n) = (
        tiled(&f.color, w, h),
        tiled(albedo, w, h),
        tiled(normal, w, h),
    );
    println!(
        "radn's U-Net beside Intel Open Image Denoise {} ({}), {w}x{h}, {} threads, median of {repeats}",
        oidn.version(),
        lib.path().display(),
        rayon::current_num_threads()
    );
    let device = radn_nn::burn::tensor::Device::flex();
    for (name, quality, clean) in [
        ("rt_hdr_alb_nrm", OidnQuality::High, false),
        ("rt_hdr_calb_cnrm_large", OidnQuality::High, true),
    ] {
        let net = radn_nn::oidn_unet::import::import(&lib, name, &device)?;
        let gmac = net.config().macs_per_pixel() * (w * h) as f64 / 1e9;
        let filter = UnetFilter::new(&net);
        let images = UnetImages {
            color: Some(&c),
            albedo: Some(&a),
            normal: Some(&n),
        };
        let ours = median_secs(repeats, || {
            filter.run(&images, None)?;
            Ok(())
        })?;
        let theirs = median_secs(repeats, || {
            oidn.beauty(&c, Some(&a), Some(&n), quality, clean)?;
            Ok(())
        })?;
        println!(
            "{name:24} radn {:7.0} ms ({:5.0} GFLOP/s)   OIDN {:7.0} ms ({:5.0} GFLOP/s)   radn/OIDN {:.2}",
            ours * 1e3,
            2.0 * gmac / ours,
            theirs * 1e3,
            2.0 * gmac / theirs,
            ours / theirs
        );
    }
    Ok(())
}

/// Times a network preset's training step on one tile and a bare conv stack of the same shape.
/// A network preset, or a network TOML file.
fn net_config(preset: &str) -> Result<radn_nn::NetConfig> {
    Ok(if std::path::Path::new(preset).is_file() {
        radn_nn::NetConfig::parse(&std::fs::read_to_string(preset)?)?
    } else {
        radn_nn::NetConfig::preset(preset)?
    })
}

/// Times the default network's convolution shapes, radn's CPU path against burn's.
fn convs(tile: usize, repeats: usize) -> Result<()> {
    let device = radn_nn::burn::tensor::Device::flex();
    let cin = crate::model::load(None, &device)?.config.input_channels();
    // guided-lean has the built-in guided model's inputs
    let gcin = crate::model::load_for(None, true, &device)?
        .config
        .input_channels();
    // the default model's input layer, residual blocks, RA predictor (h_i and average halves,
    // weight) and kernel head; then guided-lean's (width 16, 3×3 taps): input layer, residual
    // blocks, RA predictor, kernel heads and blend heads
    let shapes = [
        (cin, 32),
        (32, 32),
        (32, 16),
        (16, 1),
        (96, 25),
        (gcin, 16),
        (16, 16),
        (16, 8),
        (8, 1),
        (16, 9),
    ];
    println!(
        "3x3 convolutions on 5 x {tile}x{tile} maps, inference, {} threads (median of {repeats}):",
        rayon::current_num_threads()
    );
    println!("| cin → cout | radn ms | radn GFLOP/s | path | im2col+GEMM GFLOP/s | direct GFLOP/s | burn ms | burn GFLOP/s | speed-up |");
    println!("| --- | ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: |");
    let timings = radn_nn::bench::time_convs(&shapes, 5, tile, repeats.max(1), &device);
    for t in timings {
        println!(
            "| {} → {} | {:.0} | {:.1} | {:?} | {:.1} | {} | {:.0} | {:.1} | {:.2} |",
            t.cin,
            t.cout,
            t.radn_ms,
            t.radn_gflops(),
            t.chosen,
            t.gemm_gflops(),
            t.direct_gflops()
                .map_or("–".to_string(), |g| format!("{g:.1}")),
            t.burn_ms,
            t.burn_gflops(),
            t.burn_ms / t.radn_ms
        );
    }
    println!(
        "ceiling: one 2048x2048 GEMM (gemm crate, same threads) reaches {:.1} GFLOP/s",
        radn_nn::bench::gemm_ceiling(2048, repeats.max(1))
    );
    Ok(())
}

/// Times inference calls of a network on batches of tiles.
fn inference(
    preset: &str,
    tile: usize,
    batch: usize,
    repeats: usize,
    on: radn_nn::device::ComputeDevice,
) -> Result<()> {
    let cfg = net_config(preset)?;
    let device = on.open()?;
    let t = radn_nn::bench::time_inference(&cfg, tile, batch, repeats.max(1), &device);
    println!(
        "network '{preset}' inference on {on}, {batch} x {tile}x{tile} tile x {} frames, {} threads: {:.0} ms ({:.0} ms per tile, {:.3} MP/s of tile area), {:.1} GFLOP/s",
        cfg.frames,
        rayon::current_num_threads(),
        t.ms,
        t.ms / batch as f64,
        (batch * tile * tile) as f64 / 1e6 / (t.ms * 1e-3),
        t.forward_flops / (t.ms * 1e-3) / 1e9
    );
    Ok(())
}

fn network(
    preset: &str,
    tile: usize,
    batch: usize,
    steps: usize,
    on: radn_nn::device::ComputeDevice,
) -> Result<()> {
    use radn_nn::model::config::Backbone;
    use radn_train::bench::{time_conv_stack, time_network};
    let cfg = net_config(preset)?;
    let device = on.open_for_training()?;
    let params = radn_nn::Denoiser::new(cfg.clone(), &device).num_params();
    let net = time_network(&cfg, tile, batch, steps.max(1), &device);
    println!(
        "network '{preset}': {params} parameters, on {on}, {} threads",
        rayon::current_num_threads()
    );
    println!(
        "  training step (fwd+bwd+Adam), {batch} x {tile}x{tile} tile x {} frames: {:.0} ms ({:.0} ms per tile, {:.2} tiles/s), {:.1} GFLOP/s ({:.2} GFLOP forward)",
        cfg.frames,
        net.ms,
        net.ms / batch as f64,
        batch as f64 / (net.ms * 1e-3),
        net.gflops(),
        net.forward_flops / 1e9
    );
    if let (Some(first), Some(last)) = (net.losses.first(), net.losses.last()) {
        println!(
            "  loss on that batch: {first:.5} before the first step, {last:.5} after {} steps ({})",
            net.losses.len() - 1,
            if last < first { "lower" } else { "NOT lower" }
        );
    }
    if let Backbone::Resnet { blocks, width, .. } = &cfg.backbone {
        let stack = time_conv_stack(
            *width,
            2 * blocks,
            batch * cfg.frames,
            tile,
            steps.max(1),
            &device,
        );
        println!(
            "  bare 3x3 conv stack ({} convs at width {width}, same tile and frames): {:.0} ms, {:.1} GFLOP/s",
            2 * blocks,
            stack.ms,
            stack.gflops()
        );
        println!(
            "  network / bare stack throughput: {:.2}",
            net.gflops() / stack.gflops()
        );
    }
    Ok(())
}

/// `--oidn`: OIDN's filters on one frame, on the CPU or its CUDA device, median of `repeats`
/// after one warm-up (filters built, weights loaded).
fn oidn(
    reader: &radn_core::io::frame::FrameReader,
    path: &std::path::Path,
    repeats: usize,
    device: radn_nn::device::ComputeDevice,
) -> Result<()> {
    use radn_core::guide::{GuideFilters, OidnDenoiser, OidnDevice, OidnSettings, Prefilter};
    let kind: OidnDevice = device.into();
    let mut d = OidnDenoiser::on(kind, 0)?;
    let (f, _) = reader.read(path)?;
    let (w, h) = (f.color.width(), f.color.height());
    println!(
        "Intel Open Image Denoise {} on the {kind}, {w}x{h} ({:.3} MP), median of {repeats}",
        d.version(),
        (w * h) as f64 / 1e6
    );
    for (name, prefilter) in [
        ("noisy auxiliaries", Prefilter::Off),
        ("prefiltered (radn's guide)", Prefilter::default()),
    ] {
        let settings = OidnSettings {
            prefilter,
            ..OidnSettings::default()
        };
        let mut secs = Vec::new();
        for k in 0..=repeats.max(1) {
            let started = std::time::Instant::now();
            d.denoise_frame(&f.color, f.albedo.as_ref(), f.normal.as_ref(), &settings)
                .map_err(anyhow::Error::msg)?;
            if k > 0 {
                secs.push(started.elapsed().as_secs_f64());
            }
        }
        secs.sort_by(f64::total_cmp);
        let t = secs[secs.len() / 2];
        println!(
            "{name:28} {:9.1} ms   {:7.2} MP/s",
            t * 1e3,
            (w * h) as f64 / 1e6 / t
        );
    }
    Ok(())
}
