//! Tile datasets for training (`radn prepare`): windows of rendered sequences at several noise
//! levels, pre-warped with confidence, cut into square tiles and stored as fixed-size half-float
//! records in shards, so training reads them without decoding or aligning EXRs again.
//!
//! One record holds a header (flags; from format 2 on, each input level's exposure), then, for
//! each input level (`high`, `half`, `low`), the window's base network features
//! `[T, INPUT_CHANNELS, S, S]` and linear colour `[T, 3, S, S]`, then the centre frame's colour
//! `[3, S, S]` for each target level (`high`, `half`, `low`, `pseudo`). Tile sets prepared
//! with a guide (format 3, [`Manifest::guide`]) also hold, after each input level's colour,
//! that level's warped guide `[T, 3, S, S]` (Intel Open Image Denoise of that very render, or
//! the renderer's denoised layer). What a network reads beyond the base features is derived
//! from these at training time ([`radn_nn::infer::input::network_features`]).

use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use half::f16;
use radn_core::align::warp::Resampling;
use radn_core::align::{align_window, AlignParams};
use radn_core::guide::oidn_settings::OidnSettings;
use radn_core::guide::{GuideChoice, JobGuides, OidnGuides};
use radn_core::io::exr_file::ExrFile;
use radn_core::io::frame::{FrameReader, Requirements};
use radn_core::io::mapping::ChannelMapping;
use radn_core::io::sequence::{scene_folders, SequencePattern};
use radn_core::run::window::WindowReader;

use radn_nn::error::{NnError, Result};
use radn_nn::infer::align_params_loosened;
use radn_nn::infer::input::{color_values, features, FeatureScales};
use radn_nn::infer::schedule::NoiseSchedule;
use radn_nn::model::config::INPUT_CHANNELS;
use radn_nn::oidn_unet::prefilter::AuxPrefilter;

use crate::tile_manifest::default_pseudo_level;
pub use crate::tile_manifest::{Manifest, DEFAULT_PSEUDO_LEVEL};

/// Levels a network input can come from, least noisy first.
pub const INPUT_LEVELS: [&str; 3] = ["high", "half", "low"];
/// Levels a target can come from, least noisy last: the pseudo-reference is the cleanest.
pub const TARGET_LEVELS: [&str; 4] = ["high", "half", "low", "pseudo"];
const RECORDS_PER_SHARD: usize = 64;
/// The tile format `prepare` writes: 2 adds each input level's exposure to the header, 3 the
/// input levels' guides (in tile sets prepared with one).
pub const TILE_FORMAT: u32 = 3;

/// Header bytes of a record: flags (4) and, from format 2, one f32 exposure per input level.
fn header_bytes(format: u32) -> usize {
    if format >= 2 {
        4 + 4 * INPUT_LEVELS.len()
    } else {
        8
    }
}

/// What `prepare` was asked to do.
#[derive(Clone, Debug)]
pub struct PrepareOptions {
    /// Tile side in pixels.
    pub tile: usize,
    /// Tiles cut from each window (at seeded random positions).
    pub tiles_per_window: usize,
    /// Seed of the tile positions.
    pub seed: u64,
    /// Frames in a window.
    pub frames: usize,
    /// The level folder whose frames are the pseudo-reference target: `pseudo` (the classic
    /// denoiser, `radn pseudoref`) or `oidn` (the teacher render denoised by OIDN, datagen's
    /// `--teacher-spp`).
    pub pseudo_level: String,
    /// Each input frame's guide, stored for guided networks (none: no guide is stored).
    pub guide: GuideChoice,
    /// Threads of Intel Open Image Denoise, for `guide` `oidn` (0: every core).
    pub oidn_threads: usize,
    /// How OIDN makes the `oidn` guides; a model trained on them keeps these in its recipe.
    pub oidn: OidnSettings,
    /// Alignment's guide term ([`radn_core::align::confidence::ConfidenceParams::guide`]) for the
    /// stored windows, so a guided network can train on windows aligned as a guided
    /// model's recipe aligns them; `None`: the geometric terms alone.
    pub guide_confidence: Option<f32>,
    /// How alignment samples the side frames between pixels; a network trains on tiles
    /// prepared the way its description says inference aligns
    /// ([`radn_nn::model::config::NetConfig::resampling`]).
    pub resampling: Resampling,
    /// The most alignment's sampled-buffer terms (albedo, normal, depth) are loosened by each
    /// window's centre noise level, as a guided model's recipe aligns
    /// ([`radn_nn::infer::align_params_loosened`]), so a network trains on the windows it will
    /// see; `None`: the strict tolerances at every level (every shipped model's tiles).
    pub loosen_sampled_terms: Option<f32>,
    /// The noise schedule that loosening follows (the recipe's, so training and inference
    /// loosen alike).
    pub schedule: NoiseSchedule,
    /// OIDN's albedo and normal prefilters, to clean every frame's auxiliaries before its
    /// windows are aligned, as a converted clean-auxiliary network reads them at inference;
    /// `None`: the auxiliaries as rendered.
    pub aux_prefilter: Option<std::sync::Arc<AuxPrefilter>>,
}

impl PrepareOptions {
    /// `tiles_per_window` tiles of `tile` px per 5-frame window at positions seeded by `seed`,
    /// the default pseudo-reference level, no guide, and the geometric terms of alignment alone;
    /// bilinear resampling; the rest is set by struct update.
    pub fn new(tile: usize, tiles_per_window: usize, seed: u64) -> Self {
        Self {
            tile,
            tiles_per_window,
            seed,
            frames: 5,
            pseudo_level: default_pseudo_level(),
            guide: GuideChoice::None,
            oidn_threads: 0,
            oidn: OidnSettings::default(),
            guide_confidence: None,
            resampling: Resampling::Bilinear,
            loosen_sampled_terms: None,
            schedule: radn_nn::recipe::Recipe::for_kind(false).schedule,
            aux_prefilter: None,
        }
    }
}

/// One training tile.
#[derive(Clone, Debug)]
pub struct Tile {
    /// Per input level: features `[T, C, S, S]`.
    pub features: Vec<Vec<f32>>,
    /// Per input level: linear colour `[T, 3, S, S]`.
    pub values: Vec<Vec<f32>>,
    /// Per target level: centre colour `[3, S, S]` (None where that level is missing).
    pub targets: Vec<Option<Vec<f32>>>,
    /// Per input level: the centre frame's exposure ([`FeatureScales::exposure`]); None in
    /// tiles of format 1, prepared before it was recorded.
    pub exposure: Vec<Option<f32>>,
    /// Per input level: the warped guide `[T, 3, S, S]`, in tile sets prepared with one.
    pub guides: Vec<Option<Vec<f32>>>,
}

fn record_bytes(tile: usize, frames: usize, format: u32, guided: bool) -> usize {
    let s2 = tile * tile;
    let per_frame = INPUT_CHANNELS + 3 + 3 * usize::from(guided);
    let inputs = INPUT_LEVELS.len() * frames * per_frame * s2;
    let targets = TARGET_LEVELS.len() * 3 * s2;
    header_bytes(format) + 2 * (inputs + targets)
}

/// A small deterministic generator (SplitMix64) for tile positions and training order.
#[derive(Clone, Debug)]
pub struct SplitMix(pub u64);

impl SplitMix {
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// A uniform integer in `0..n`.
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
}

/// Cuts tiles from every scene under `data` (datagen layout `<scene>/<level>/frame_####.exr`)
/// into `out`. Returns the manifest.
pub fn prepare(
    data: &Path,
    out: &Path,
    opts: &PrepareOptions,
    mut progress: impl FnMut(usize, usize),
) -> Result<Manifest> {
    let scenes = scenes_fitting(scene_folders(data, "high")?, opts.tile)?;
    std::fs::create_dir_all(out).map_err(|e| io_err(out, e))?;
    clear_tile_folder(out)?;
    let guided = opts.guide.is_some();
    let rb = record_bytes(opts.tile, opts.frames, TILE_FORMAT, guided);
    let oidn = match opts.guide {
        GuideChoice::Oidn => {
            let g = OidnGuides::new(opts.oidn_threads)?;
            g.configure(opts.oidn);
            Some(std::sync::Arc::new(g))
        }
        _ => None,
    };
    let mut align = AlignParams {
        resampling: opts.resampling,
        ..AlignParams::default()
    };
    align.confidence.guide = opts.guide_confidence.filter(|_| guided);
    let mut writer = ShardWriter::new(out, rb);
    let mut with_pseudo = 0;
    let total: usize = scenes.len();
    for (si, scene) in scenes.iter().enumerate() {
        let pattern = SequencePattern::from_folder(&scene.join("high"))?;
        let numbers = pattern.frames(None)?;
        let level_files = |level: &str| -> Result<Option<Vec<PathBuf>>> {
            let dir = scene.join(level);
            if !dir.is_dir() {
                return Ok(None);
            }
            let p = SequencePattern::from_folder(&dir)?;
            Ok(Some(numbers.iter().map(|&f| p.path(f)).collect()))
        };
        let mapping = scene_mapping(&pattern.path(numbers[0]))?;
        let mut input_reader = FrameReader::new(mapping.clone(), Requirements::DENOISE);
        input_reader.guide = opts.guide.layer();
        let pseudo_reader = FrameReader::new(mapping, Requirements::COLOR_ONLY);
        let mut input_files: Vec<Vec<PathBuf>> = Vec::new();
        for level in INPUT_LEVELS {
            input_files.push(level_files(level)?.ok_or_else(|| {
                NnError::Config(format!(
                    "scene '{}' has no '{level}' level",
                    scene.display()
                ))
            })?);
        }
        let pseudo = level_files(&opts.pseudo_level)?;
        let clean_aux = |f: &mut radn_core::io::frame::Frame| -> radn_core::error::Result<()> {
            if let Some(p) = &opts.aux_prefilter {
                let (albedo, normal) = p.clean(f, None)?;
                f.albedo = albedo.or(f.albedo.take());
                f.normal = normal.or(f.normal.take());
            }
            Ok(())
        };
        let mut inputs: Vec<WindowReader> = input_files
            .iter()
            .map(|f| {
                let w =
                    WindowReader::new(&input_reader, f, opts.frames / 2).with_transform(&clean_aux);
                match &oidn {
                    // each input render's own OIDN result
                    Some(g) => w.with_guides(JobGuides::Oidn {
                        guides: g.clone(),
                        originals: f.clone(),
                    }),
                    None => w,
                }
            })
            .collect();
        let mut size: Option<(usize, usize)> = None;
        for (k, _) in numbers.iter().enumerate() {
            let mut feats = Vec::new();
            let mut vals = Vec::new();
            let mut exposures = Vec::new();
            let mut guides = Vec::new();
            for level in inputs.iter_mut() {
                // the centre frame's scales, known before aligning (it is the frame as
                // rendered): its noise level sets the alignment, its exposure is stored
                let (win, scales) = {
                    let frames = level.read(k)?;
                    let c = frames[opts.frames / 2].expect("a window's centre frame exists");
                    let scales =
                        FeatureScales::of_centre(&c.color, c.albedo.as_ref(), c.depth.as_ref());
                    let params = align_params_loosened(
                        align,
                        opts.loosen_sampled_terms,
                        scales.noise_level,
                        &opts.schedule,
                    );
                    (align_window(&frames, &params), scales)
                };
                feats.push(features(&win));
                vals.push(color_values(&win));
                exposures.push(scales.exposure);
                if guided {
                    guides.push(guide_values(&win));
                }
            }
            let (w, h) = *size.get_or_insert_with(|| {
                let c = inputs[0].frame(k);
                (c.width(), c.height())
            });
            if w < opts.tile || h < opts.tile {
                return Err(NnError::Config(format!(
                    "scene '{}' is {w}x{h}, smaller than the {} px tile",
                    scene.display(),
                    opts.tile
                )));
            }
            // a level rendered for some frames only (a split's `ref/`) targets those
            let pseudo_frame = pseudo
                .as_ref()
                .filter(|p| p[k].exists())
                .map(|p| pseudo_reader.read(&p[k]).map(|r| r.0))
                .transpose()?;
            let mut targets: Vec<Option<&[f32]>> = inputs
                .iter()
                .map(|l| Some(l.frame(k).color.data()))
                .collect();
            targets.push(pseudo_frame.as_ref().map(|p| p.color.data()));
            let mut rng =
                SplitMix(opts.seed ^ ((si as u64) << 32) ^ (k as u64).wrapping_mul(0x9E37_79B9));
            for _ in 0..opts.tiles_per_window {
                let (x0, y0) = (rng.below(w - opts.tile + 1), rng.below(h - opts.tile + 1));
                let record = encode(
                    opts,
                    (w, h),
                    (x0, y0),
                    &exposures,
                    LevelPlanes {
                        feats: &feats,
                        vals: &vals,
                        guides: &guides,
                    },
                    &targets,
                );
                writer.write(&record)?;
                if targets[3].is_some() {
                    with_pseudo += 1;
                }
            }
        }
        progress(si + 1, total);
    }
    let records = writer.finish()?;
    let manifest = Manifest {
        format: TILE_FORMAT,
        tile: opts.tile,
        frames: opts.frames,
        feature_channels: INPUT_CHANNELS,
        input_levels: INPUT_LEVELS.iter().map(|s| s.to_string()).collect(),
        target_levels: TARGET_LEVELS.iter().map(|s| s.to_string()).collect(),
        records,
        records_per_shard: RECORDS_PER_SHARD,
        record_bytes: rb,
        seed: opts.seed,
        scenes: scenes
            .iter()
            .map(|s| {
                s.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default()
            })
            .collect(),
        with_pseudo,
        pseudo_level: opts.pseudo_level.clone(),
        guide: match &opts.guide {
            GuideChoice::None => None,
            GuideChoice::Oidn => Some("oidn".into()),
            GuideChoice::Denoised => Some("denoised".into()),
            GuideChoice::Layer(l) => Some(l.clone()),
        },
        oidn: match opts.guide {
            GuideChoice::Oidn => opts.oidn,
            _ => OidnSettings::default(),
        },
        guide_confidence: align.confidence.guide,
        resampling: opts.resampling,
        loosen_sampled_terms: opts.loosen_sampled_terms,
        aux_prefilters: opts.aux_prefilter.as_ref().map(|p| p.names()),
    };
    let text = serde_json::to_string_pretty(&manifest).expect("manifest serialises");
    radn_core::io::output::write_bytes_atomically(&out.join("manifest.json"), text.as_bytes())?;
    Ok(manifest)
}

/// The channel preset a scene's frames fit (Cycles' layers, the generic layout), read from one
/// row of its first frame, so one tile set mixes renderers.
/// The scenes whose frames hold a `tile`-pixel tile; the others are left out with a warning
/// (a split may mix resolutions), and none left is an error. Read from the headers, before any
/// work.
fn scenes_fitting(scenes: Vec<PathBuf>, tile: usize) -> Result<Vec<PathBuf>> {
    let mut kept = Vec::new();
    for scene in scenes {
        let pattern = SequencePattern::from_folder(&scene.join("high"))?;
        let first = pattern.path(pattern.frames(None)?[0]);
        let (w, h) = ExrFile::read_size(&first)?;
        if w < tile || h < tile {
            tracing::warn!(
                "left out scene '{}': its frames are {w}x{h}, smaller than the {tile} px tile",
                scene.display()
            );
        } else {
            kept.push(scene);
        }
    }
    if kept.is_empty() {
        return Err(NnError::Config(format!(
            "no scene's frames hold a {tile} px tile: choose a smaller --tile"
        )));
    }
    Ok(kept)
}

fn scene_mapping(probe: &Path) -> Result<ChannelMapping> {
    let names = ExrFile::read_rows(probe, 0..1)?.channel_names();
    ChannelMapping::detect(&names).ok_or_else(|| {
        NnError::Config(format!(
            "'{}': no channel preset fits its channels ({})",
            probe.display(),
            names.join(", ")
        ))
    })
}

fn io_err(p: &Path, e: std::io::Error) -> NnError {
    NnError::Save {
        path: p.to_path_buf(),
        detail: e.to_string(),
    }
}

/// One window's per-input-level planes: base features, colour and (in guided sets) guides.
struct LevelPlanes<'a> {
    feats: &'a [Vec<f32>],
    vals: &'a [Vec<f32>],
    guides: &'a [Vec<f32>],
}

/// Every frame's warped guide, `[T, 3, H, W]`.
fn guide_values(win: &radn_core::align::AlignedWindow) -> Vec<f32> {
    win.frames
        .iter()
        .flat_map(|f| {
            f.guide
                .as_ref()
                .expect("a guided tile set's frames carry guides")
                .data()
                .iter()
                .copied()
        })
        .collect()
}

/// One record: the tile at `(x0, y0)` of `w × h` frames; per input level its features,
/// colour and (where the set stores them) guides.
fn encode(
    opts: &PrepareOptions,
    (w, h): (usize, usize),
    (x0, y0): (usize, usize),
    exposures: &[f32],
    planes: LevelPlanes,
    targets: &[Option<&[f32]>],
) -> Vec<u8> {
    let s = opts.tile;
    let guided = opts.guide.is_some();
    let mut out = Vec::with_capacity(record_bytes(s, opts.frames, TILE_FORMAT, guided));
    let flags: u32 = if targets[3].is_some() { 1 } else { 0 };
    out.extend_from_slice(&flags.to_le_bytes());
    for e in exposures {
        out.extend_from_slice(&e.to_le_bytes());
    }
    debug_assert_eq!(out.len(), header_bytes(TILE_FORMAT));
    let mut crop = |data: &[f32], planes: usize| {
        for p in 0..planes {
            for y in y0..y0 + s {
                let row = &data[p * w * h + y * w + x0..p * w * h + y * w + x0 + s];
                for v in row {
                    out.extend_from_slice(&f16::from_f32(*v).to_le_bytes());
                }
            }
        }
    };
    for (i, (f, v)) in planes.feats.iter().zip(planes.vals).enumerate() {
        crop(f, opts.frames * INPUT_CHANNELS);
        crop(v, opts.frames * 3);
        if guided {
            crop(&planes.guides[i], opts.frames * 3);
        }
    }
    for t in targets {
        match t {
            Some(t) => crop(t, 3),
            None => crop(&vec![0.0; 3 * w * h], 3),
        }
    }
    out
}

/// Writes tile records into shards of [`RECORDS_PER_SHARD`], each through a temporary file
/// renamed into place once full (or at the end), so a killed run leaves no shard cut short.
struct ShardWriter {
    dir: PathBuf,
    record_bytes: usize,
    count: usize,
    file: Option<(BufWriter<File>, tempfile::NamedTempFile)>,
}

impl ShardWriter {
    fn new(dir: &Path, record_bytes: usize) -> Self {
        Self {
            dir: dir.to_path_buf(),
            record_bytes,
            count: 0,
            file: None,
        }
    }

    fn write(&mut self, record: &[u8]) -> Result<()> {
        debug_assert_eq!(record.len(), self.record_bytes);
        if self.count.is_multiple_of(RECORDS_PER_SHARD) {
            self.close_shard()?;
            let tmp = radn_core::io::output::output_tempfile(&self.dir, ".radn-", ".bin.tmp")
                .map_err(|e| io_err(&self.dir, e))?;
            let f = tmp
                .as_file()
                .try_clone()
                .map_err(|e| io_err(tmp.path(), e))?;
            self.file = Some((BufWriter::new(f), tmp));
        }
        let (f, tmp) = self.file.as_mut().expect("open shard");
        f.write_all(record).map_err(|e| io_err(tmp.path(), e))?;
        self.count += 1;
        Ok(())
    }

    /// Flushes the open shard and gives it its name.
    fn close_shard(&mut self) -> Result<()> {
        if let Some((mut f, tmp)) = self.file.take() {
            let p = shard_path(&self.dir, (self.count - 1) / RECORDS_PER_SHARD);
            f.flush().map_err(|e| io_err(&p, e))?;
            f.get_ref().sync_all().map_err(|e| io_err(&p, e))?;
            tmp.persist(&p).map_err(|e| io_err(&p, e.error))?;
        }
        Ok(())
    }

    fn finish(mut self) -> Result<usize> {
        self.close_shard()?;
        Ok(self.count)
    }
}

/// Readies `out` for a new tile set: removes the debris of killed runs and the earlier set's
/// manifest and shards, so that until this run writes its manifest (last) the folder is not
/// mistaken for a complete tile set.
fn clear_tile_folder(out: &Path) -> Result<()> {
    radn_core::io::output_locks::remove_stale(out)?;
    let manifest = out.join("manifest.json");
    if manifest.exists() {
        std::fs::remove_file(&manifest).map_err(|e| io_err(&manifest, e))?;
    }
    for e in std::fs::read_dir(out)
        .map_err(|e| io_err(out, e))?
        .flatten()
    {
        let name = e.file_name();
        let name = name.to_string_lossy();
        if name.starts_with("shard_") && name.ends_with(".bin") {
            std::fs::remove_file(e.path()).map_err(|err| io_err(&e.path(), err))?;
        }
    }
    Ok(())
}

fn shard_path(dir: &Path, i: usize) -> PathBuf {
    dir.join(format!("shard_{i:05}.bin"))
}

/// A prepared tile dataset, read record by record.
#[derive(Clone, Debug)]
pub struct TileDataset {
    dir: PathBuf,
    /// Its manifest.
    pub manifest: Manifest,
}

impl TileDataset {
    /// Opens a folder made by [`prepare`].
    pub fn open(dir: &Path) -> Result<Self> {
        let err = |detail: String| NnError::Tiles {
            path: dir.to_path_buf(),
            detail,
        };
        let text = std::fs::read_to_string(dir.join("manifest.json")).map_err(|e| {
            err(format!(
                "no manifest.json ({e}): not a tile set, or `radn prepare` did not finish \
                     (it writes the manifest last; run it again)"
            ))
        })?;
        let manifest: Manifest =
            serde_json::from_str(&text).map_err(|e| err(format!("bad manifest.json ({e})")))?;
        if manifest.feature_channels != INPUT_CHANNELS
            || manifest.format > TILE_FORMAT
            || (manifest.guide.is_some() && manifest.format < 3)
            || manifest.record_bytes
                != record_bytes(
                    manifest.tile,
                    manifest.frames,
                    manifest.format,
                    manifest.guide.is_some(),
                )
        {
            return Err(err(
                "the manifest does not match this version of radn's tile layout".into(),
            ));
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest,
        })
    }

    /// Number of tiles.
    pub fn len(&self) -> usize {
        self.manifest.records
    }

    /// True when there are no tiles.
    pub fn is_empty(&self) -> bool {
        self.manifest.records == 0
    }

    /// Reads tile `i`.
    pub fn get(&self, i: usize) -> Result<Tile> {
        let m = &self.manifest;
        let p = shard_path(&self.dir, i / m.records_per_shard);
        let err = |detail: String| NnError::Tiles {
            path: p.clone(),
            detail,
        };
        let mut f = File::open(&p).map_err(|e| err(e.to_string()))?;
        f.seek(SeekFrom::Start(
            ((i % m.records_per_shard) * m.record_bytes) as u64,
        ))
        .map_err(|e| err(e.to_string()))?;
        let mut buf = vec![0u8; m.record_bytes];
        f.read_exact(&mut buf)
            .map_err(|_| err(format!("record {i} is truncated")))?;
        let flags = u32::from_le_bytes([buf[0], buf[1], buf[2], buf[3]]);
        let exposure = (0..m.input_levels.len())
            .map(|l| {
                (m.format >= 2).then(|| {
                    let at = 4 + 4 * l;
                    f32::from_le_bytes([buf[at], buf[at + 1], buf[at + 2], buf[at + 3]])
                })
            })
            .collect();
        let mut pos = header_bytes(m.format);
        let mut take = |n: usize| -> Vec<f32> {
            let v = buf[pos..pos + 2 * n]
                .chunks_exact(2)
                .map(|b| f16::from_le_bytes([b[0], b[1]]).to_f32())
                .collect();
            pos += 2 * n;
            v
        };
        let s2 = m.tile * m.tile;
        let mut features = Vec::new();
        let mut values = Vec::new();
        let mut guides = Vec::new();
        for _ in 0..m.input_levels.len() {
            features.push(take(m.frames * m.feature_channels * s2));
            values.push(take(m.frames * 3 * s2));
            guides.push(m.guide.is_some().then(|| take(m.frames * 3 * s2)));
        }
        let mut targets = Vec::new();
        for (k, _) in m.target_levels.iter().enumerate() {
            let t = take(3 * s2);
            targets.push(if k == 3 && flags & 1 == 0 {
                None
            } else {
                Some(t)
            });
        }
        Ok(Tile {
            features,
            values,
            targets,
            exposure,
            guides,
        })
    }
}
