//! OIDN's Tensor Archive (TZA) format: the container its trained weights ship in. A blob starts
//! with the magic `0x41D7`, a major and minor version (2.x), and the offset of a table at its
//! end; the table names each tensor with its shape, layout (`oihw` or `x`), element type
//! (`f` f32 or `h` f16) and the offset of its data. Every read is bounds-checked, so a
//! truncated or corrupt blob is an error, never a panic.

use std::collections::BTreeMap;

/// The magic number a TZA blob starts with.
const MAGIC: u16 = 0x41D7;
/// The only major version radn reads (OIDN 2.x writes it).
const MAJOR: u8 = 2;

/// One named tensor of an archive, widened to `f32`.
#[derive(Clone, Debug, PartialEq)]
pub struct TzaTensor {
    /// Its dimensions (`[O, I, H, W]` for a convolution weight, `[N]` for a bias).
    pub dims: Vec<usize>,
    /// Its values in row-major order of `dims`.
    pub values: Vec<f32>,
    /// Whether it was stored as f16 (OIDN's weights are).
    pub half: bool,
}

/// What is wrong with a blob that is not a readable TZA archive.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TzaError {
    /// The blob is shorter than its own table says.
    #[error("truncated weights blob ({0})")]
    Truncated(&'static str),
    /// The first bytes are not the TZA magic number.
    #[error("not a Tensor Archive (magic {0:#06x}, expected 0x41d7)")]
    Magic(u16),
    /// A version radn does not read.
    #[error("unsupported Tensor Archive version {0}.{1} (radn reads 2.x)")]
    Version(u8, u8),
    /// A table entry that makes no sense.
    #[error("corrupt weights blob: {0}")]
    Corrupt(String),
}

/// A cursor over the blob that refuses to read past its end.
struct Reader<'a> {
    blob: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], TzaError> {
        let end = self.at.checked_add(n).ok_or(TzaError::Truncated(what))?;
        let bytes = self
            .blob
            .get(self.at..end)
            .ok_or(TzaError::Truncated(what))?;
        self.at = end;
        Ok(bytes)
    }

    fn u8(&mut self, what: &'static str) -> Result<u8, TzaError> {
        Ok(self.take(1, what)?[0])
    }

    fn u16(&mut self, what: &'static str) -> Result<u16, TzaError> {
        Ok(u16::from_le_bytes(self.take(2, what)?.try_into().unwrap()))
    }

    fn u32(&mut self, what: &'static str) -> Result<u32, TzaError> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }

    fn u64(&mut self, what: &'static str) -> Result<u64, TzaError> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
}

/// The archive's version and the bytes it spans from its start (the end of its table), read
/// from the header and table alone: how much of a library's read-only data a blob occupies
/// when its symbol carries no size.
pub fn extent(blob: &[u8]) -> Result<usize, TzaError> {
    walk(blob, |_, _, _| Ok(())).map(|(_, end)| end)
}

/// Parses a whole archive into its named tensors.
pub fn parse(blob: &[u8]) -> Result<BTreeMap<String, TzaTensor>, TzaError> {
    let mut out = BTreeMap::new();
    walk(blob, |name, dims, (half, data)| {
        let values = if half {
            data.chunks_exact(2)
                .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
                .collect()
        } else {
            data.chunks_exact(4)
                .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
                .collect()
        };
        if out
            .insert(name.to_string(), TzaTensor { dims, values, half })
            .is_some()
        {
            return Err(TzaError::Corrupt(format!("tensor '{name}' appears twice")));
        }
        Ok(())
    })?;
    Ok(out)
}

/// Reads the header and every table entry, handing each tensor's name, dimensions, element
/// type and data bytes to `each`; returns the version and the offset just past the table.
fn walk(
    blob: &[u8],
    mut each: impl FnMut(&str, Vec<usize>, (bool, &[u8])) -> Result<(), TzaError>,
) -> Result<((u8, u8), usize), TzaError> {
    let mut r = Reader { blob, at: 0 };
    let magic = r.u16("header")?;
    if magic != MAGIC {
        return Err(TzaError::Magic(magic));
    }
    let version = (r.u8("header")?, r.u8("header")?);
    if version.0 != MAJOR {
        return Err(TzaError::Version(version.0, version.1));
    }
    let table = r.u64("header")?;
    r.at = usize::try_from(table).map_err(|_| TzaError::Truncated("table"))?;
    let count = r.u32("table")?;
    for _ in 0..count {
        let len = r.u16("table")? as usize;
        let name = std::str::from_utf8(r.take(len, "table")?)
            .map_err(|_| TzaError::Corrupt("a tensor name is not UTF-8".into()))?;
        let ndims = r.u8("table")? as usize;
        let mut dims = Vec::with_capacity(ndims);
        for _ in 0..ndims {
            dims.push(r.u32("table")? as usize);
        }
        let layout = r.take(ndims, "table")?;
        if layout != b"x" && layout != b"oihw" {
            return Err(TzaError::Corrupt(format!(
                "tensor '{name}' has layout '{}'",
                String::from_utf8_lossy(layout)
            )));
        }
        let half = match r.u8("table")? {
            b'h' => true,
            b'f' => false,
            t => {
                return Err(TzaError::Corrupt(format!(
                    "tensor '{name}' has element type '{}'",
                    t as char
                )))
            }
        };
        let offset = usize::try_from(r.u64("table")?).map_err(|_| TzaError::Truncated("data"))?;
        let elems = dims
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .ok_or_else(|| TzaError::Corrupt(format!("tensor '{name}' is too large")))?;
        let bytes = elems * if half { 2 } else { 4 };
        let data = offset
            .checked_add(bytes)
            .and_then(|end| blob.get(offset..end))
            .ok_or(TzaError::Truncated("tensor data"))?;
        each(name, dims, (half, data))?;
    }
    Ok((version, r.at))
}

/// Writes tensors as a TZA 2.0 archive (data 64-byte aligned, table last), as OIDN's training
/// tools do: for tests, and for handing weights back to OIDN.
pub fn write(tensors: &BTreeMap<String, TzaTensor>) -> Vec<u8> {
    fn pad(out: &mut Vec<u8>) {
        while !out.len().is_multiple_of(64) {
            out.push(0);
        }
    }
    let mut out = Vec::new();
    out.extend_from_slice(&MAGIC.to_le_bytes());
    out.extend_from_slice(&[MAJOR, 0]);
    out.extend_from_slice(&0u64.to_le_bytes());
    let mut offsets = Vec::new();
    for t in tensors.values() {
        pad(&mut out);
        offsets.push(out.len() as u64);
        for &v in &t.values {
            if t.half {
                out.extend_from_slice(&half::f16::from_f32(v).to_le_bytes());
            } else {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    pad(&mut out);
    let table = out.len() as u64;
    out[4..12].copy_from_slice(&table.to_le_bytes());
    out.extend_from_slice(&(tensors.len() as u32).to_le_bytes());
    for ((name, t), offset) in tensors.iter().zip(offsets) {
        out.extend_from_slice(&(name.len() as u16).to_le_bytes());
        out.extend_from_slice(name.as_bytes());
        out.push(t.dims.len() as u8);
        for &d in &t.dims {
            out.extend_from_slice(&(d as u32).to_le_bytes());
        }
        out.extend_from_slice(if t.dims.len() == 4 { b"oihw" } else { b"x" });
        out.push(if t.half { b'h' } else { b'f' });
        out.extend_from_slice(&offset.to_le_bytes());
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn archive() -> BTreeMap<String, TzaTensor> {
        let mut m = BTreeMap::new();
        m.insert(
            "conv.weight".to_string(),
            TzaTensor {
                dims: vec![2, 1, 3, 3],
                values: (0..18).map(|i| i as f32 * 0.25 - 2.0).collect(),
                half: true,
            },
        );
        m.insert(
            "conv.bias".to_string(),
            TzaTensor {
                dims: vec![2],
                values: vec![0.5, -1.0e-3],
                half: false,
            },
        );
        m
    }

    #[test]
    fn an_archive_reads_back_what_was_written_and_spans_its_table() {
        let blob = write(&archive());
        assert_eq!(parse(&blob).unwrap(), archive());
        assert_eq!(extent(&blob).unwrap(), blob.len());
        // trailing bytes (the rest of a library's read-only data) are not part of it
        let mut longer = blob.clone();
        longer.extend_from_slice(&[7; 100]);
        assert_eq!(extent(&longer).unwrap(), blob.len());
    }

    #[test]
    fn truncated_or_corrupt_blobs_are_errors_never_panics() {
        let blob = write(&archive());
        for n in 0..blob.len() {
            assert!(parse(&blob[..n]).is_err(), "cut at {n}");
        }
        let mut bad = blob.clone();
        bad[0] = 0;
        assert!(matches!(parse(&bad), Err(TzaError::Magic(_))));
        let mut bad = blob.clone();
        bad[2] = 3;
        assert_eq!(parse(&bad), Err(TzaError::Version(3, 0)));
        // a data offset pointing past the end
        let mut bad = blob.clone();
        let n = bad.len();
        bad[n - 8..].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(parse(&bad).is_err());
        // every single corrupted byte is at worst an error
        for i in 0..blob.len() {
            let mut b = blob.clone();
            b[i] ^= 0xA5;
            let _ = parse(&b);
        }
    }
}
