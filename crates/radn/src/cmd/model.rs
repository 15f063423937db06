//! `radn model`: a model file's network and recipe, and a copy of it with its recipe tuned, so a
//! setting chosen by measurement ships inside the model rather than as a flag every run repeats.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use radn_nn::device::ComputeDevice;

use crate::input::{check_threshold, tune_pairs};

/// Arguments of `radn model`.
#[derive(clap::Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct Args {
    /// Import one of OIDN's trained U-Nets, or convert one, instead.
    #[command(subcommand)]
    pub action: Option<Action>,
    /// The model file (SafeTensors, as `radn train` or `radn model import-oidn` writes).
    #[arg(required = true)]
    pub file: Option<PathBuf>,
    /// Change a recipe setting in the copy written to --out (`radn denoise --tune help` lists
    /// the keys).
    #[arg(long, value_name = "KEY=VALUE", requires = "out")]
    pub tune: Vec<String>,
    /// Where the tuned copy goes (a new file: neither the model nor any other file is replaced).
    #[arg(short, long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

/// What `radn model` can do besides showing and tuning a file.
#[derive(clap::Subcommand)]
pub enum Action {
    /// Read one of OIDN's trained U-Nets from an OIDN 2.x core library into a radn model file
    /// (runnable by `radn denoise --method spatial --model FILE`).
    ImportOidn(ImportArgs),
    /// Convert an imported U-Net into the paper's spatio-temporal network: Robust Average
    /// blocks behind closed gates, so that it is the per-frame U-Net until `radn train` opens
    /// them (runnable by `radn denoise --method temporal --model FILE`).
    Convert(ConvertArgs),
}

/// Arguments of `radn model convert`.
#[derive(clap::Args)]
pub struct ConvertArgs {
    /// The imported U-Net (`radn model import-oidn` writes it).
    pub unet: PathBuf,
    /// Encoder levels that get a block (0: the input's resolution, 4: the bottleneck).
    #[arg(long, value_delimiter = ',', default_value = "0,1,2,3")]
    pub levels: Vec<usize>,
    /// Frames per window (odd).
    #[arg(long, default_value_t = 5)]
    pub frames: usize,
    /// Alignment's colour tolerance for the windows (none: the colour term is left out).
    #[arg(long, value_name = "TOLERANCE")]
    pub color_confidence: Option<f32>,
    /// Where the window is moved onto the centre: images, or each frame's encoder levels.
    #[arg(long, default_value = "images", value_parser = ["images", "features"])]
    pub warp: String,
    /// Auxiliaries the U-Net reads: as rendered, or cleaned first by OIDN's standard albedo
    /// and normal prefilters (for clean-auxiliary weights such as rt_hdr_calb_cnrm_large).
    #[arg(long, default_value = "rendered", value_parser = ["rendered", "prefiltered"])]
    pub aux: String,
    /// Frames of the aligned window (odd) whose colour is averaged into the centre frame's
    /// input before the encoder (1: the centre as rendered).
    #[arg(long, default_value_t = 1)]
    pub input_frames: usize,
    /// A learned average of the window's input at the centre frame, closed until trained
    /// (`radn train` with `input_blend = true` opens it).
    #[arg(long)]
    pub input_blend: bool,
    /// The temporal pass over the results at this strength (σ in local RMS of each frame's
    /// render noise; the guided recipe's floor and noise box); off when not given.
    #[arg(long, value_name = "STRENGTH")]
    pub stabilize: Option<f32>,
    /// The model file to write (a new file: nothing is replaced).
    #[arg(short, long, value_name = "FILE")]
    pub out: PathBuf,
}

/// Writes the converted network of an imported U-Net.
fn convert(a: ConvertArgs) -> Result<()> {
    use radn_nn::oidn_unet::temporal::{AuxSource, TemporalConfig, TemporalUnet, WarpSpace};
    if a.out.exists() {
        bail!(
            "'{}' exists; radn model convert writes a new file",
            a.out.display()
        );
    }
    let device = ComputeDevice::Cpu.open()?;
    let unet = radn_nn::oidn_unet::store::load(&a.unet, &device)?;
    let config = TemporalConfig {
        frames: a.frames,
        levels: a.levels,
        color_confidence: a.color_confidence,
        warp: match a.warp.as_str() {
            "features" => WarpSpace::Features,
            _ => WarpSpace::Images,
        },
        aux: match a.aux.as_str() {
            "prefiltered" => AuxSource::Prefiltered,
            _ => AuxSource::Rendered,
        },
        input_frames: a.input_frames,
        input_blend: a.input_blend,
        stabilize: a.stabilize.map(|strength| {
            let tuned = radn_nn::recipe::Recipe::for_kind(true)
                .stabilize
                .expect("the guided recipe has a temporal pass");
            radn_core::post::stabilize::StabilizeSettings { strength, ..tuned }
        }),
    };
    let net = TemporalUnet::convert(unet, config, &device)
        .with_context(|| format!("converting '{}'", a.unet.display()))?;
    radn_nn::oidn_unet::temporal_store::save(&net, &a.out)
        .with_context(|| format!("writing '{}'", a.out.display()))?;
    println!(
        "{}: '{}' converted, blocks at levels {:?} over {} frames, gates closed",
        a.out.display(),
        net.unet.config().weights,
        net.config().levels,
        net.config().frames
    );
    Ok(())
}

/// Arguments of `radn model import-oidn`.
#[derive(clap::Args)]
pub struct ImportArgs {
    /// The OIDN library (its core library, the main library beside it, or their folder);
    /// default: the one `radn denoise` finds (RADN_OIDN_LIBRARY, OIDN_DIR, the loader path,
    /// the pyoidn or bpy wheel, a Blender on PATH).
    pub library: Option<PathBuf>,
    /// OIDN's name for the model: rt_hdr_alb_nrm, rt_hdr_calb_cnrm_large, rt_alb_large,
    /// rt_nrm_large, … (`--weights list` lists the library's).
    #[arg(long, default_value = radn_nn::oidn_unet::import::DEFAULT_WEIGHTS)]
    pub weights: String,
    /// The model file to write (a new file: nothing is replaced).
    #[arg(short, long, value_name = "FILE", required_unless_present = "list")]
    pub out: Option<PathBuf>,
    /// List the models the library carries instead.
    #[arg(long)]
    pub list: bool,
}

/// Imports OIDN's weights into a model file.
fn import_oidn(a: ImportArgs) -> Result<()> {
    use radn_nn::oidn_unet::library::WeightsLibrary;
    let library = match a.library {
        Some(p) => p,
        None => radn_core::guide::OidnDenoiser::new(1)
            .context("finding OIDN (name its library: radn model import-oidn LIBRARY)")?
            .library()
            .to_path_buf(),
    };
    let lib = WeightsLibrary::open(&library)?;
    if a.list {
        println!("{}: {}", lib.path().display(), lib.names().join(" "));
        return Ok(());
    }
    let out = a.out.expect("clap requires --out without --list");
    if out.exists() {
        bail!(
            "'{}' exists; radn model import-oidn writes a new file",
            out.display()
        );
    }
    let device = ComputeDevice::Cpu.open()?;
    let net = radn_nn::oidn_unet::import::import(&lib, &a.weights, &device)?;
    radn_nn::oidn_unet::store::save(&net, &out)
        .with_context(|| format!("writing '{}'", out.display()))?;
    let c = net.config();
    println!(
        "{}: OIDN {} '{}' ({:?} layers, {} parameters) from {}",
        out.display(),
        c.oidn_version,
        c.weights,
        c.layers,
        c.parameters(),
        lib.path().display()
    );
    Ok(())
}

/// Prints the network and recipe, or writes the copy with its recipe tuned.
pub fn run(a: Args) -> Result<()> {
    match a.action {
        Some(Action::ImportOidn(i)) => return import_oidn(i),
        Some(Action::Convert(c)) => return convert(c),
        None => {}
    }
    let file = a.file.expect("clap requires a file without a subcommand");
    let device = ComputeDevice::Cpu.open()?;
    if radn_nn::oidn_unet::store::is_unet_file(&file) {
        if a.out.is_some() {
            bail!(
                "'{}' is an imported OIDN U-Net: it has no recipe to tune",
                file.display()
            );
        }
        let net = radn_nn::oidn_unet::store::load(&file, &device)?;
        println!(
            "# {}\n# an imported OIDN U-Net: {} parameters, {:.0} multiply-adds per pixel\n\n{}",
            file.display(),
            net.config().parameters(),
            net.config().macs_per_pixel(),
            net.config().to_toml()
        );
        return Ok(());
    }
    if radn_nn::oidn_unet::temporal_store::is_temporal_file(&file) {
        if a.out.is_some() {
            bail!(
                "'{}' is a converted OIDN U-Net: it has no recipe to tune",
                file.display()
            );
        }
        let net = radn_nn::oidn_unet::temporal_store::load(&file, &device)?;
        let gates: Vec<String> = net
            .temporal
            .openness()
            .iter()
            .map(|g| format!("{g:.3}"))
            .chain(
                net.temporal
                    .input_openness()
                    .map(|g| format!("input {g:.3}")),
            )
            .collect();
        println!(
            "# {}\n# OIDN's U-Net converted into a spatio-temporal network (radn denoise \
             --method temporal); gate openness per blended level: {}\n\n# window\n{}\n# U-Net\n{}",
            file.display(),
            gates.join(" "),
            net.config().to_toml(),
            net.unet.config().to_toml()
        );
        return Ok(());
    }
    let mut model = radn_nn::model::store::load(&file, &device)?;
    let Some(out) = a.out else {
        println!(
            "# {}\n\n# network\n{}",
            file.display(),
            model.config.to_toml()
        );
        println!("# recipe\n{}", model.recipe.to_toml());
        return Ok(());
    };
    if out.exists() {
        bail!("'{}' exists; radn model writes a new file", out.display());
    }
    for (key, value) in tune_pairs(&a.tune)? {
        model.recipe.set(key, value).map_err(anyhow::Error::msg)?;
    }
    if let Some(t) = model.recipe.threshold {
        check_threshold(t, &model.config)?;
    }
    radn_nn::model::store::save(&model, &out)
        .with_context(|| format!("writing the tuned model to '{}'", out.display()))?;
    println!("{}: recipe\n{}", out.display(), model.recipe.to_toml());
    Ok(())
}
