//! The snapshot file (docs/snapshots.md): a versioned, self-describing container for the
//! state of a whole twin at one simulated instant, bounded in size, checked whole before
//! anything in it is used.
//!
//! ```text
//! "M6PSNAP\0"                magic, 8 bytes
//! u32 LE                     format (FORMAT)
//! u32 LE                     header length H (at most MAX_HEADER)
//! H bytes                    header, JSON (SnapshotHeader): the build, the scenario's text,
//!                            the seed, the instant, the sections' names and lengths
//! sections                   their bytes, one after the other, in the header's order
//! u32 LE                     CRC-32C of every byte before it
//! ```
//!
//! A snapshot holds a build's internal state, laid out as that build lays it out: only the
//! build that took it reads it. Any other file is refused with the reason and the file's
//! name, never misread: not a snapshot (magic), another format, another build, another
//! scenario than the one given, a file cut short or longer than it says, a corrupted byte
//! (the CRC), a header that does not parse, a file over [`MAX_BYTES`].

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// The file's first bytes.
pub const MAGIC: &[u8; 8] = b"M6PSNAP\0";
/// The container's format; a reader reads its own only.
pub const FORMAT: u32 = 1;
/// The largest snapshot file read or written (what an outside file can make the twin
/// allocate).
pub const MAX_BYTES: u64 = 1 << 30;
/// The largest header.
pub const MAX_HEADER: u32 = 16 << 20;

/// What a snapshot says of itself.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SnapshotHeader {
    /// The build that took it ([`build_id`]).
    pub build: String,
    /// The scenario's name.
    pub scenario_name: String,
    /// The scenario's text, as the run read it.
    pub scenario_toml: String,
    /// The run's seed.
    pub seed: u64,
    /// The simulated instant, ns since the run's start.
    pub t_ns: u64,
    /// The sections, in file order: name and length in bytes.
    pub sections: Vec<(String, u64)>,
}

/// A snapshot read whole and checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SnapshotFile {
    /// Its header.
    pub header: SnapshotHeader,
    /// Its sections' bytes, in the header's order.
    pub sections: Vec<Vec<u8>>,
}

/// Why a file is not a snapshot this build can use.
#[derive(Debug, thiserror::Error)]
pub enum SnapshotFileError {
    /// It could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Its first bytes are not a snapshot's.
    #[error("{path}: not an m6p-twin snapshot (it does not begin with M6PSNAP)")]
    NotASnapshot {
        /// The file.
        path: PathBuf,
    },
    /// Another container format.
    #[error("{path}: snapshot format {found}; this build reads format {FORMAT}")]
    Format {
        /// The file.
        path: PathBuf,
        /// Its format.
        found: u32,
    },
    /// Larger than [`MAX_BYTES`] (or its header than [`MAX_HEADER`]).
    #[error("{path}: {what} of {bytes} bytes is over the limit of {limit} bytes")]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// The file or its header.
        what: &'static str,
        /// Its size.
        bytes: u64,
        /// The limit.
        limit: u64,
    },
    /// Shorter or longer than its header says.
    #[error("{path}: cut short or padded: its header says {expected} bytes, the file has {found}")]
    Length {
        /// The file.
        path: PathBuf,
        /// The length the header implies.
        expected: u64,
        /// The file's length.
        found: u64,
    },
    /// A byte changed since it was written.
    #[error("{path}: corrupted: CRC-32C {computed:08x} of its contents, {stored:08x} written")]
    Corrupted {
        /// The file.
        path: PathBuf,
        /// The CRC it carries.
        stored: u32,
        /// The CRC of what it holds.
        computed: u32,
    },
    /// The header does not parse.
    #[error("{path}: its header is not a snapshot header: {why}")]
    Header {
        /// The file.
        path: PathBuf,
        /// Why.
        why: String,
    },
    /// Taken by another build.
    #[error(
        "{path}: taken by another build of m6p-twin ({taken_by}; this is {this}): a snapshot \
         holds the internal state of the build that took it, so only that build reads it"
    )]
    OtherBuild {
        /// The file.
        path: PathBuf,
        /// The build that took it.
        taken_by: String,
        /// This build.
        this: String,
    },
    /// Of another scenario than the one given.
    #[error(
        "{path}: a snapshot of scenario `{taken_of}`, not of `{given}` (or of another version \
         of its text)"
    )]
    OtherScenario {
        /// The file.
        path: PathBuf,
        /// The scenario it was taken of.
        taken_of: String,
        /// The scenario given.
        given: String,
    },
}

impl SnapshotFile {
    /// The file's bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut header = self.header.clone();
        header.sections = header
            .sections
            .iter()
            .zip(&self.sections)
            .map(|((name, _), data)| (name.clone(), data.len() as u64))
            .collect();
        let json = serde_json::to_vec(&header).unwrap_or_default();
        let mut out =
            Vec::with_capacity(20 + json.len() + self.sections.iter().map(Vec::len).sum::<usize>());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&FORMAT.to_le_bytes());
        out.extend_from_slice(&(json.len() as u32).to_le_bytes());
        out.extend_from_slice(&json);
        for s in &self.sections {
            out.extend_from_slice(s);
        }
        let crc = crc32c::crc32c(&out);
        out.extend_from_slice(&crc.to_le_bytes());
        out
    }

    /// Read `bytes` (the contents of `path`, named in errors) and check them whole: the
    /// magic, the format, the lengths, the CRC, the header. Not yet the build or the
    /// scenario ([`SnapshotFile::check`]).
    pub fn decode(path: &Path, bytes: &[u8]) -> Result<SnapshotFile, SnapshotFileError> {
        let p = || path.to_path_buf();
        if bytes.len() < MAGIC.len() || &bytes[..MAGIC.len()] != MAGIC {
            return Err(SnapshotFileError::NotASnapshot { path: p() });
        }
        let found = bytes.len() as u64;
        if found > MAX_BYTES {
            return Err(SnapshotFileError::TooLarge {
                path: p(),
                what: "the file",
                bytes: found,
                limit: MAX_BYTES,
            });
        }
        let short = |expected: u64| SnapshotFileError::Length {
            path: p(),
            expected,
            found,
        };
        let u32_at = |at: usize| -> Option<u32> {
            let b = bytes.get(at..at + 4)?;
            Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        };
        let format = u32_at(8).ok_or_else(|| short(20))?;
        if format != FORMAT {
            return Err(SnapshotFileError::Format {
                path: p(),
                found: format,
            });
        }
        let header_len = u32_at(12).ok_or_else(|| short(20))?;
        if header_len > MAX_HEADER {
            return Err(SnapshotFileError::TooLarge {
                path: p(),
                what: "its header",
                bytes: u64::from(header_len),
                limit: u64::from(MAX_HEADER),
            });
        }
        let body = 16 + header_len as usize;
        if bytes.len() < body + 4 {
            return Err(short(body as u64 + 4));
        }
        // The CRC first: a header read from a corrupted file says nothing.
        let end = bytes.len() - 4;
        let stored = u32_at(end).unwrap_or_default();
        let computed = crc32c::crc32c(&bytes[..end]);
        let header: Result<SnapshotHeader, _> = serde_json::from_slice(&bytes[16..body]);
        let sections_len = header.as_ref().ok().map(|h| {
            h.sections
                .iter()
                .fold(0u64, |n, (_, len)| n.saturating_add(*len))
        });
        // A file cut short or padded says so, rather than "corrupted", when its header can
        // still be read.
        if let Some(n) = sections_len {
            let expected = (body as u64 + 4).saturating_add(n);
            if expected != found {
                return Err(short(expected));
            }
        }
        if stored != computed {
            return Err(SnapshotFileError::Corrupted {
                path: p(),
                stored,
                computed,
            });
        }
        let header = header.map_err(|e| SnapshotFileError::Header {
            path: p(),
            why: e.to_string(),
        })?;
        let mut at = body;
        let mut sections = Vec::with_capacity(header.sections.len());
        for (_, len) in &header.sections {
            let len = usize::try_from(*len).unwrap_or(usize::MAX);
            let data = bytes
                .get(at..at.saturating_add(len))
                .ok_or_else(|| short(found + 1))?;
            sections.push(data.to_vec());
            at += len;
        }
        Ok(SnapshotFile { header, sections })
    }

    /// Whether this build can use it for `scenario_toml` (`None`: any scenario): the same
    /// build ([`build_id`]) and the same scenario text.
    pub fn check(
        &self,
        path: &Path,
        build: &str,
        scenario: Option<(&str, &str)>,
    ) -> Result<(), SnapshotFileError> {
        if self.header.build != build {
            return Err(SnapshotFileError::OtherBuild {
                path: path.to_path_buf(),
                taken_by: self.header.build.clone(),
                this: build.to_owned(),
            });
        }
        if let Some((name, text)) = scenario
            && text != self.header.scenario_toml
        {
            return Err(SnapshotFileError::OtherScenario {
                path: path.to_path_buf(),
                taken_of: self.header.scenario_name.clone(),
                given: name.to_owned(),
            });
        }
        Ok(())
    }

    /// Read the file at `path` (at most [`MAX_BYTES`]) and check it whole.
    pub fn read(path: &Path) -> Result<SnapshotFile, SnapshotFileError> {
        use std::io::Read as _;
        let io = |source| SnapshotFileError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut bytes = Vec::new();
        std::fs::File::open(path)
            .map_err(io)?
            .take(MAX_BYTES + 1)
            .read_to_end(&mut bytes)
            .map_err(io)?;
        SnapshotFile::decode(path, &bytes)
    }

    /// Write it to `path`: beside it first, put in place when whole.
    pub fn write(&self, path: &Path) -> Result<(), SnapshotFileError> {
        let io = |source| SnapshotFileError::Io {
            path: path.to_path_buf(),
            source,
        };
        let bytes = self.encode();
        if bytes.len() as u64 > MAX_BYTES {
            return Err(SnapshotFileError::TooLarge {
                path: path.to_path_buf(),
                what: "the snapshot",
                bytes: bytes.len() as u64,
                limit: MAX_BYTES,
            });
        }
        let mut tmp = path.as_os_str().to_owned();
        tmp.push(".part");
        let tmp = PathBuf::from(tmp);
        std::fs::write(&tmp, &bytes).map_err(io)?;
        std::fs::rename(&tmp, path).map_err(io)
    }
}

/// The CRC-32C and length of the file at `path`, read a piece at a time (an executable with
/// its debug information is a hundred megabytes: it is not held in memory whole).
fn crc_of_file(path: std::path::PathBuf) -> std::io::Result<(u32, u64)> {
    use std::io::Read as _;
    let mut f = std::fs::File::open(path)?;
    let mut buf = vec![0u8; 1 << 16];
    let (mut crc, mut len) = (0u32, 0u64);
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            return Ok((crc, len));
        }
        crc = crc32c::crc32c_append(crc, &buf[..n]);
        len += n as u64;
    }
}

/// This build's identity: the package's version and the CRC-32C and length of the running
/// executable, so that two builds of one source (debug and release, another compiler) are
/// told apart as surely as two sources are.
pub fn build_id() -> String {
    static ID: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    ID.get_or_init(|| {
        let exe = std::env::current_exe()
            .and_then(crc_of_file)
            .map(|(crc, len)| format!("{crc:08x}-{len}"))
            .unwrap_or_else(|e| format!("unknown executable ({e})"));
        format!("m6p-twin {} exe {exe}", env!("CARGO_PKG_VERSION"))
    })
    .clone()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn sample() -> SnapshotFile {
        SnapshotFile {
            header: SnapshotHeader {
                build: "b1".into(),
                scenario_name: "default".into(),
                scenario_toml: "name = \"default\"\n".into(),
                seed: 7,
                t_ns: 90_000_000_000,
                sections: vec![("bus".into(), 0), ("fc".into(), 0)],
            },
            sections: vec![vec![1, 2, 3], vec![4; 10]],
        }
    }

    /// What is written reads back the same; this build and scenario are taken.
    #[test]
    fn a_snapshot_reads_back_as_written() {
        let s = sample();
        let bytes = s.encode();
        let back = SnapshotFile::decode(Path::new("s.snap"), &bytes).unwrap();
        assert_eq!(back.sections, s.sections);
        assert_eq!(back.header.sections, [("bus".into(), 3), ("fc".into(), 10)]);
        back.check(
            Path::new("s.snap"),
            "b1",
            Some(("default", "name = \"default\"\n")),
        )
        .unwrap();
    }

    /// Every other file is refused with the file's name and why.
    #[test]
    fn other_files_are_refused_naming_the_file_and_why() {
        let p = Path::new("x.snap");
        let good = sample().encode();
        let why = |bytes: &[u8]| SnapshotFile::decode(p, bytes).unwrap_err().to_string();
        assert!(why(b"PK\x03\x04 a zip").contains("x.snap: not an m6p-twin snapshot"));
        let mut other_format = good.clone();
        other_format[8] = 2;
        assert!(why(&other_format).contains("snapshot format 2; this build reads format 1"));
        let cut = why(&good[..good.len() - 5]);
        assert!(cut.contains("cut short or padded"), "{cut}");
        let mut padded = good.clone();
        padded.push(0);
        assert!(why(&padded).contains("cut short or padded"));
        for i in [20, good.len() - 8, good.len() - 1] {
            let mut flipped = good.clone();
            flipped[i] ^= 0x10;
            let w = why(&flipped);
            assert!(w.contains("x.snap: corrupted: CRC-32C"), "byte {i}: {w}");
        }
        let mut huge_header = good.clone();
        huge_header[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(why(&huge_header).contains("its header of 4294967295 bytes is over the limit"));
        let s = SnapshotFile::decode(p, &good).unwrap();
        let w = s.check(p, "b2", None).unwrap_err().to_string();
        assert!(
            w.contains("taken by another build of m6p-twin (b1; this is b2)"),
            "{w}"
        );
        let w = s
            .check(p, "b1", Some(("full-day", "x")))
            .unwrap_err()
            .to_string();
        assert!(
            w.contains("a snapshot of scenario `default`, not of `full-day`"),
            "{w}"
        );
    }

    /// The build's identity is the same within a process and names the executable.
    #[test]
    fn the_build_id_names_the_version_and_the_executable() {
        let id = build_id();
        assert_eq!(id, build_id());
        assert!(id.starts_with("m6p-twin ") && id.contains(" exe "), "{id}");
    }

    proptest::proptest! {
        /// No input makes the reader panic or allocate past the file.
        #[test]
        fn any_bytes_are_read_or_refused(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..200)) {
            let _ = SnapshotFile::decode(Path::new("f"), &bytes);
            let mut with_magic = MAGIC.to_vec();
            with_magic.extend_from_slice(&bytes);
            let _ = SnapshotFile::decode(Path::new("f"), &with_magic);
        }
    }
}
