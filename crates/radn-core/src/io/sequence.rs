//! Image sequences: file-name patterns (`####`, `%04d`, `$F4`) and frame ranges (`1001-1100x2`).

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// A file-name pattern with one frame-number field.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SequencePattern {
    text: String,
    prefix: String,
    suffix: String,
    padding: usize,
}

impl SequencePattern {
    /// Parses a pattern: a run of `#` (one digit each), `%d`/`%0Nd`, or `$F`/`$FN` (Houdini).
    /// A plain path without a frame field is a one-file "sequence" only usable with no range.
    pub fn parse(text: &str) -> Result<Self> {
        let err = |detail: &str| Error::Parse {
            what: "sequence pattern",
            text: text.into(),
            detail: detail.into(),
        };
        let fields = [find_hashes(text), find_printf(text), find_houdini(text)];
        let found: Vec<(usize, usize, usize)> = fields.into_iter().flatten().collect();
        match found.len() {
            0 => Err(err("no frame-number field: use ####, %04d or $F4")),
            1 => {
                let (start, end, padding) = found[0];
                let (prefix, suffix) = (&text[..start], &text[end..]);
                if [
                    find_hashes(suffix),
                    find_printf(suffix),
                    find_houdini(suffix),
                ]
                .iter()
                .any(Option::is_some)
                {
                    return Err(err("more than one frame-number field"));
                }
                Ok(Self {
                    text: text.into(),
                    prefix: prefix.into(),
                    suffix: suffix.into(),
                    padding,
                })
            }
            _ => Err(err("more than one frame-number field")),
        }
    }

    /// Infers the pattern of a folder of numbered EXR files (`frame_0001.exr` → `frame_####.exr`).
    /// A folder holding several differently named sequences is an error that lists them.
    pub fn from_folder(dir: &Path) -> Result<Self> {
        let entries = std::fs::read_dir(dir).map_err(|source| Error::Open {
            path: dir.to_path_buf(),
            source,
        })?;
        let mut patterns: Vec<String> = Vec::new();
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if !name.to_ascii_lowercase().ends_with(".exr") || name.starts_with('.') {
                continue;
            }
            // the last run of digits is the frame number
            let Some(end) = name.rfind(|c: char| c.is_ascii_digit()) else {
                continue;
            };
            let start = name[..=end]
                .rfind(|c: char| !c.is_ascii_digit())
                .map_or(0, |i| i + 1);
            let p = format!(
                "{}{}{}",
                &name[..start],
                "#".repeat(end + 1 - start),
                &name[end + 1..]
            );
            if !patterns.contains(&p) {
                patterns.push(p);
            }
        }
        patterns.sort();
        let text = dir.display().to_string();
        match patterns.len() {
            0 => Err(Error::EmptySequence {
                pattern: format!("{text}/*.exr"),
            }),
            1 => Self::parse(&dir.join(&patterns[0]).to_string_lossy()),
            _ => Err(Error::Parse {
                what: "sequence folder",
                text,
                detail: format!(
                    "it holds several sequences ({}); give a pattern instead",
                    patterns.join(", ")
                ),
            }),
        }
    }

    /// A pattern (`####`, `%04d`, `$F4`) or, for an existing folder, the pattern of the
    /// numbered EXRs inside it.
    pub fn parse_or_folder(text: &str) -> Result<Self> {
        let p = Path::new(text);
        if p.is_dir() {
            Self::from_folder(p)
        } else {
            Self::parse(text)
        }
    }

    /// The pattern as the user wrote it.
    pub fn as_str(&self) -> &str {
        &self.text
    }

    /// The path of one frame.
    pub fn path(&self, frame: i64) -> PathBuf {
        let digits = if frame < 0 {
            format!("-{:0width$}", -frame, width = self.padding)
        } else {
            format!("{:0width$}", frame, width = self.padding)
        };
        PathBuf::from(format!("{}{}{}", self.prefix, digits, self.suffix))
    }

    /// The frame numbers of the files on disk that match, sorted.
    pub fn discover(&self) -> Result<Vec<i64>> {
        let full = Path::new(&self.prefix);
        let (dir, file_prefix) = if self.prefix.ends_with('/') || self.prefix.is_empty() {
            (
                if self.prefix.is_empty() {
                    PathBuf::from(".")
                } else {
                    PathBuf::from(&self.prefix)
                },
                String::new(),
            )
        } else {
            let dir = full
                .parent()
                .map(Path::to_path_buf)
                .filter(|p| !p.as_os_str().is_empty())
                .unwrap_or_else(|| PathBuf::from("."));
            (
                dir,
                full.file_name()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default(),
            )
        };
        if self.suffix.contains('/') {
            return Err(Error::Parse {
                what: "sequence pattern",
                text: self.text.clone(),
                detail: "the frame number must be in the file name, not in a folder name".into(),
            });
        }
        let entries = std::fs::read_dir(&dir).map_err(|source| Error::Open {
            path: dir.clone(),
            source,
        })?;
        let mut frames = Vec::new();
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some(rest) = name.strip_prefix(&file_prefix) else {
                continue;
            };
            let Some(num) = rest.strip_suffix(&self.suffix) else {
                continue;
            };
            let digits = num.strip_prefix('-').unwrap_or(num);
            if digits.is_empty()
                || !digits.bytes().all(|b| b.is_ascii_digit())
                || digits.len() < self.padding
            {
                continue;
            }
            if digits.len() > self.padding && digits.starts_with('0') {
                continue; // over-padded: not this pattern's file
            }
            if let Ok(n) = num.parse::<i64>() {
                frames.push(n);
            }
        }
        frames.sort_unstable();
        frames.dedup();
        if frames.is_empty() {
            return Err(Error::EmptySequence {
                pattern: self.text.clone(),
            });
        }
        Ok(frames)
    }

    /// The frames to process: the given range (every file must exist), or all files found.
    pub fn frames(&self, range: Option<&FrameRange>) -> Result<Vec<i64>> {
        match range {
            Some(r) => {
                let frames = r.frames();
                for &f in &frames {
                    let p = self.path(f);
                    if !p.is_file() {
                        return Err(Error::MissingFrame { frame: f, path: p });
                    }
                }
                Ok(frames)
            }
            None => {
                let frames = self.discover()?;
                // a gap inside a discovered sequence is a missing frame, not a shorter shot
                if let (Some(&a), Some(&b)) = (frames.first(), frames.last()) {
                    let step = frames
                        .windows(2)
                        .map(|w| w[1] - w[0])
                        .min()
                        .unwrap_or(1)
                        .max(1);
                    let mut f = a;
                    while f <= b {
                        if frames.binary_search(&f).is_err() {
                            return Err(Error::MissingFrame {
                                frame: f,
                                path: self.path(f),
                            });
                        }
                        f += step;
                    }
                }
                Ok(frames)
            }
        }
    }
}

impl SequencePattern {
    /// The frames a run over `wanted` (sorted, existing frames) reads: every frame of the
    /// sequence from the first wanted to the last, and up to `reach` more on each side (fewer
    /// where the sequence ends). Windows at the ends of a frame range then see the neighbours
    /// they see in a run over the whole sequence, so a shot split into ranges (on a farm, or
    /// by hand) denoises exactly as it does whole. The sequence's frame step is that of the
    /// files on disk; a frame missing inside the span is an error, as it is for a whole run.
    pub fn with_context(&self, wanted: &[i64], reach: usize) -> Result<Vec<i64>> {
        let (Some(&first), Some(&last)) = (wanted.first(), wanted.last()) else {
            return Err(Error::EmptySequence {
                pattern: self.text.clone(),
            });
        };
        let on_disk = self.discover()?;
        let step = on_disk
            .windows(2)
            .map(|w| w[1] - w[0])
            .min()
            .unwrap_or(1)
            .max(1);
        let has = |f: i64| on_disk.binary_search(&f).is_ok();
        // extend outwards until the reach or the sequence's end; a hole before the end is a
        // missing frame
        let extend = |dir: i64| -> Result<i64> {
            let mut end = if dir < 0 { first } else { last };
            for _ in 0..reach {
                let f = end + dir * step;
                if has(f) {
                    end = f;
                } else if on_disk.iter().any(|&g| (g - f) * dir > 0) {
                    return Err(Error::MissingFrame {
                        frame: f,
                        path: self.path(f),
                    });
                } else {
                    break;
                }
            }
            Ok(end)
        };
        let (lo, hi) = (extend(-1)?, extend(1)?);
        let frames: Vec<i64> = (lo..=hi).step_by(step as usize).collect();
        for &f in frames.iter().chain(wanted) {
            if !has(f) || (f - lo) % step != 0 {
                return Err(Error::MissingFrame {
                    frame: f,
                    path: self.path(f),
                });
            }
        }
        Ok(frames)
    }
}

impl std::fmt::Display for SequencePattern {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.text)
    }
}

fn find_hashes(s: &str) -> Option<(usize, usize, usize)> {
    let start = s.find('#')?;
    let len = s[start..].bytes().take_while(|&b| b == b'#').count();
    Some((start, start + len, len))
}

fn find_printf(s: &str) -> Option<(usize, usize, usize)> {
    let b = s.as_bytes();
    let mut i = 0;
    while let Some(off) = s[i..].find('%') {
        let start = i + off;
        let mut j = start + 1;
        let mut width = String::new();
        while j < b.len() && b[j].is_ascii_digit() {
            width.push(b[j] as char);
            j += 1;
        }
        if j < b.len() && b[j] == b'd' {
            let pad = width.trim_start_matches('0').parse().unwrap_or(1).max(1);
            return Some((start, j + 1, pad));
        }
        i = start + 1;
    }
    None
}

fn find_houdini(s: &str) -> Option<(usize, usize, usize)> {
    let start = s.find("$F")?;
    let b = s.as_bytes();
    let mut j = start + 2;
    let mut width = String::new();
    while j < b.len() && b[j].is_ascii_digit() {
        width.push(b[j] as char);
        j += 1;
    }
    Some((start, j, width.parse().unwrap_or(1).max(1)))
}

/// An inclusive frame range with a step: `1001-1100`, `1001-1100x2`, or a single `1001`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameRange {
    /// First frame.
    pub first: i64,
    /// Last frame (inclusive).
    pub last: i64,
    /// Step between frames (≥ 1).
    pub step: i64,
}

impl FrameRange {
    /// Parses `a`, `a-b` or `a-b[xstep]` (also `a:b` and `a-b:step`); negative frames allowed.
    pub fn parse(text: &str) -> Result<Self> {
        let err = |d: &str| Error::Parse {
            what: "frame range",
            text: text.into(),
            detail: d.into(),
        };
        let t = text.trim();
        let (range, step) = match t
            .rfind(['x', 'X'])
            .or_else(|| t.match_indices(':').nth(1).map(|(i, _)| i))
        {
            Some(i) => (
                &t[..i],
                t[i + 1..]
                    .parse::<i64>()
                    .map_err(|_| err("the step is not a whole number"))?,
            ),
            None => (t, 1),
        };
        if step < 1 {
            return Err(err("the step must be at least 1"));
        }
        // split at a '-' or ':' that is not a leading sign
        let sep = range
            .char_indices()
            .skip(1)
            .find(|&(_, c)| c == '-' || c == ':')
            .map(|(i, _)| i);
        let (first, last) = match sep {
            Some(i) => (&range[..i], &range[i + 1..]),
            None => (range, range),
        };
        let first: i64 = first
            .trim()
            .parse()
            .map_err(|_| err("expected FIRST-LAST[xSTEP], e.g. 1001-1100x2"))?;
        let last: i64 = last
            .trim()
            .parse()
            .map_err(|_| err("expected FIRST-LAST[xSTEP], e.g. 1001-1100x2"))?;
        if last < first {
            return Err(err("the last frame comes before the first"));
        }
        Ok(Self { first, last, step })
    }

    /// The frame numbers in the range.
    pub fn frames(&self) -> Vec<i64> {
        (self.first..=self.last)
            .step_by(self.step as usize)
            .collect()
    }
}

impl std::str::FromStr for FrameRange {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Self::parse(s)
    }
}

/// The frames of a sequence given as a pattern or a folder, optionally only those of a frame
/// range (`first-last[xstep]`): (frame number, path) in frame order.
pub fn sequence_files(spec: &str, frames: Option<&str>) -> Result<Vec<(i64, PathBuf)>> {
    let pattern = SequencePattern::parse_or_folder(spec)?;
    let range = frames.map(FrameRange::parse).transpose()?;
    Ok(pattern
        .frames(range.as_ref())?
        .into_iter()
        .map(|f| (f, pattern.path(f)))
        .collect())
}

/// The scene folders of a rendered dataset (the data generator's layout
/// `<scene>/<level>/frame_####.exr`): every folder under `data` with a `level` folder, in
/// name order, or `data` itself when it is one scene.
pub fn scene_folders(data: &Path, level: &str) -> Result<Vec<PathBuf>> {
    if data.join(level).is_dir() {
        return Ok(vec![data.to_path_buf()]);
    }
    let mut v: Vec<PathBuf> = std::fs::read_dir(data)
        .map_err(|source| Error::Open {
            path: data.to_path_buf(),
            source,
        })?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.join(level).is_dir())
        .collect();
    v.sort();
    if v.is_empty() {
        return Err(Error::NoScenes {
            path: data.to_path_buf(),
            level: level.into(),
        });
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_pattern_styles_make_the_same_path() {
        for p in [
            "shot/beauty.####.exr",
            "shot/beauty.%04d.exr",
            "shot/beauty.$F4.exr",
        ] {
            let s = SequencePattern::parse(p).unwrap();
            assert_eq!(s.path(1001), PathBuf::from("shot/beauty.1001.exr"), "{p}");
            assert_eq!(s.path(7), PathBuf::from("shot/beauty.0007.exr"), "{p}");
        }
        assert_eq!(
            SequencePattern::parse("a.%d.exr").unwrap().path(12),
            PathBuf::from("a.12.exr")
        );
        assert_eq!(
            SequencePattern::parse("a.$F.exr").unwrap().path(3),
            PathBuf::from("a.3.exr")
        );
    }

    #[test]
    fn bad_patterns_are_refused() {
        assert!(SequencePattern::parse("beauty.exr").is_err());
        assert!(SequencePattern::parse("b.####.%04d.exr").is_err());
    }

    #[test]
    fn ranges_parse_with_steps_and_signs() {
        assert_eq!(FrameRange::parse("1001-1100").unwrap().frames().len(), 100);
        assert_eq!(
            FrameRange::parse("1001-1010x3").unwrap().frames(),
            vec![1001, 1004, 1007, 1010]
        );
        assert_eq!(
            FrameRange::parse("-2-2").unwrap().frames(),
            vec![-2, -1, 0, 1, 2]
        );
        assert_eq!(FrameRange::parse("5").unwrap().frames(), vec![5]);
        assert_eq!(FrameRange::parse("1:9:4").unwrap().frames(), vec![1, 5, 9]);
        assert!(FrameRange::parse("10-1").is_err());
        assert!(FrameRange::parse("1-10x0").is_err());
    }

    #[test]
    fn folders_infer_their_pattern() {
        let dir = tempfile::tempdir().unwrap();
        for f in [7, 8, 9] {
            std::fs::write(dir.path().join(format!("shot_v2.{f:04}.exr")), b"").unwrap();
        }
        let p = SequencePattern::parse_or_folder(&dir.path().to_string_lossy()).unwrap();
        assert_eq!(p.discover().unwrap(), vec![7, 8, 9]);
        assert!(p.as_str().ends_with("shot_v2.####.exr"), "{p}");
        std::fs::write(dir.path().join("other.0001.exr"), b"").unwrap();
        let e = SequencePattern::from_folder(dir.path())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("several sequences") && e.contains("other.####.exr"),
            "{e}"
        );
    }

    #[test]
    fn discovery_and_missing_frames() {
        let dir = tempfile::tempdir().unwrap();
        for f in [1, 2, 4] {
            std::fs::write(dir.path().join(format!("f.{f:04}.exr")), b"").unwrap();
        }
        std::fs::write(dir.path().join("f.00003.exr"), b"").unwrap(); // other padding: ignored
        std::fs::write(dir.path().join("g.0003.exr"), b"").unwrap();
        let pat = SequencePattern::parse(&format!("{}/f.####.exr", dir.path().display())).unwrap();
        assert_eq!(pat.discover().unwrap(), vec![1, 2, 4]);
        let e = pat.frames(None).unwrap_err().to_string();
        assert!(e.contains("frame 3") && e.contains("f.0003.exr"), "{e}");
        let e = pat
            .frames(Some(&FrameRange::parse("1-4").unwrap()))
            .unwrap_err()
            .to_string();
        assert!(e.contains("f.0003.exr"), "{e}");
        assert_eq!(
            pat.frames(Some(&FrameRange::parse("1-2").unwrap()))
                .unwrap(),
            vec![1, 2]
        );
    }

    #[test]
    fn a_range_reads_its_neighbours_up_to_the_sequence_ends() {
        let dir = tempfile::tempdir().unwrap();
        let seq = |frames: &[i64]| {
            for e in std::fs::read_dir(dir.path()).unwrap() {
                std::fs::remove_file(e.unwrap().path()).unwrap();
            }
            for f in frames {
                std::fs::write(dir.path().join(format!("f.{f:04}.exr")), b"").unwrap();
            }
            SequencePattern::parse(&format!("{}/f.####.exr", dir.path().display())).unwrap()
        };
        let pat = seq(&(1001..=1009).collect::<Vec<_>>());
        // inside the shot: two frames each side
        assert_eq!(
            pat.with_context(&[1004, 1005], 2).unwrap(),
            (1002..=1007).collect::<Vec<_>>()
        );
        // at its start: only what exists
        assert_eq!(
            pat.with_context(&[1001, 1002], 3).unwrap(),
            (1001..=1005).collect::<Vec<_>>()
        );
        // a stepped range reads every frame between its frames
        assert_eq!(
            pat.with_context(&[1003, 1005, 1007], 1).unwrap(),
            (1002..=1008).collect::<Vec<_>>()
        );
        // a shot rendered on twos keeps its step
        let pat = seq(&[10, 12, 14, 16, 18]);
        assert_eq!(pat.with_context(&[14], 1).unwrap(), vec![12, 14, 16]);
        // a hole the windows would reach is a missing frame; one beyond the reach is not
        let pat = seq(&[1, 2, 3, 4, 5, 7, 8]);
        let e = pat.with_context(&[4], 2).unwrap_err().to_string();
        assert!(e.contains("frame 6") && e.contains("f.0006.exr"), "{e}");
        assert_eq!(pat.with_context(&[2], 2).unwrap(), vec![1, 2, 3, 4]);
        // and so is one between the wanted frames
        let e = pat.with_context(&[5, 7], 0).unwrap_err().to_string();
        assert!(e.contains("frame 6"), "{e}");
    }
}
