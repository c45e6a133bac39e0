//! [`read_policy_file`]: a blob file (`*.blob`, the bytes of [`PolicyBlob::as_bytes`]) read
//! straight into a private, heap-allocated [`PolicyBlob`], reading at most its size + 1
//! bytes — so `--policy /dev/zero` or a wrong file is refused at once, and memory use is
//! one blob whatever the file.

use std::fs::File;
use std::io::{self, Read};
use std::path::Path;

use shm_schemas::PolicyBlob;

/// Size in bytes of a blob file: exactly one [`PolicyBlob`].
pub const POLICY_FILE_BYTES: usize = size_of::<PolicyBlob>();

/// Why [`read_policy_file`] or [`read_policy_blob`] refused a file. The messages name the
/// sizes; the caller names the file (as with [`std::fs::read`]).
#[derive(Debug)]
pub enum PolicyFileError {
    /// Opening or reading failed.
    Io(io::Error),
    /// The file ends before a whole blob.
    TooShort {
        /// Bytes the file holds.
        actual: u64,
        /// Bytes a blob has ([`POLICY_FILE_BYTES`]).
        expected: usize,
    },
    /// The file goes on after a whole blob (at most one byte more is read).
    TooLong {
        /// The file's length when it is a regular file; `None` for a device or a pipe
        /// (e.g. `/dev/zero`), whose length is not known.
        actual: Option<u64>,
        /// Bytes a blob has ([`POLICY_FILE_BYTES`]).
        expected: usize,
    },
}

impl core::fmt::Display for PolicyFileError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Io(e) => e.fmt(f),
            Self::TooShort { actual, expected } => write!(
                f,
                "{actual} bytes, shorter than a policy blob ({expected} bytes)"
            ),
            Self::TooLong {
                actual: Some(actual),
                expected,
            } => write!(
                f,
                "{actual} bytes, longer than a policy blob ({expected} bytes)"
            ),
            Self::TooLong {
                actual: None,
                expected,
            } => write!(f, "longer than a policy blob ({expected} bytes)"),
        }
    }
}

impl std::error::Error for PolicyFileError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::Io(e) => Some(e),
            Self::TooShort { .. } | Self::TooLong { .. } => None,
        }
    }
}

impl From<io::Error> for PolicyFileError {
    fn from(e: io::Error) -> Self {
        Self::Io(e)
    }
}

/// For callers whose error carries an [`io::Error`]: I/O errors as they are, a wrong
/// length as [`io::ErrorKind::InvalidData`] with this error's message.
impl From<PolicyFileError> for io::Error {
    fn from(e: PolicyFileError) -> Self {
        match e {
            PolicyFileError::Io(e) => e,
            other => io::Error::new(io::ErrorKind::InvalidData, other),
        }
    }
}

/// Reads the blob file at `path` into a new private blob: [`read_policy_blob`] on the
/// opened file, with the file's length in [`PolicyFileError::TooLong`] when it is a
/// regular file.
///
/// The blob is **not** validated: hand it to [`crate::PolicyLoader`] (or call
/// [`PolicyBlob::validate`] first for the field-level error).
///
/// # Errors
/// [`PolicyFileError`]: I/O, or a length other than [`POLICY_FILE_BYTES`].
pub fn read_policy_file(path: &Path) -> Result<Box<PolicyBlob>, PolicyFileError> {
    let file = File::open(path)?;
    match read_policy_blob(&file) {
        Err(PolicyFileError::TooLong { expected, .. }) => Err(PolicyFileError::TooLong {
            actual: file
                .metadata()
                .ok()
                .filter(|m| m.is_file())
                .map(|m| m.len()),
            expected,
        }),
        other => other,
    }
}

/// Reads one blob's bytes from `reader` into a new private blob (the only allocation),
/// reading at most [`POLICY_FILE_BYTES`] + 1 bytes: the extra byte tells a longer input
/// from an exact one. Not validated (see [`read_policy_file`]).
///
/// # Errors
/// [`PolicyFileError`]: I/O, fewer bytes than a blob ([`PolicyFileError::TooShort`]) or
/// more ([`PolicyFileError::TooLong`], with `actual: None`).
pub fn read_policy_blob(reader: impl Read) -> Result<Box<PolicyBlob>, PolicyFileError> {
    let mut limited = reader.take(POLICY_FILE_BYTES as u64 + 1);
    let mut blob = PolicyBlob::new_boxed();
    let got = read_up_to(&mut limited, blob.as_bytes_mut())?;
    if got < POLICY_FILE_BYTES {
        return Err(PolicyFileError::TooShort {
            actual: got as u64,
            expected: POLICY_FILE_BYTES,
        });
    }
    if read_up_to(&mut limited, &mut [0u8; 1])? != 0 {
        return Err(PolicyFileError::TooLong {
            actual: None,
            expected: POLICY_FILE_BYTES,
        });
    }
    Ok(blob)
}

/// Fills `buf` from `reader` until it is full or the input ends; the bytes read.
fn read_up_to(reader: &mut impl Read, buf: &mut [u8]) -> io::Result<usize> {
    let mut filled = 0;
    while filled < buf.len() {
        match reader.read(&mut buf[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(filled)
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use shm_schemas::PolicyBlobBuilder;

    use super::*;

    /// A file in the temp folder, removed on drop.
    struct TempFile(PathBuf);

    impl TempFile {
        fn with(name: &str, bytes: &[u8]) -> Self {
            let path = std::env::temp_dir().join(format!(
                "foresight-policy-{}-{name}.blob",
                std::process::id()
            ));
            std::fs::write(&path, bytes).unwrap();
            Self(path)
        }
    }

    impl Drop for TempFile {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }

    fn valid() -> Box<PolicyBlob> {
        PolicyBlobBuilder::random(3, 9, 17, &[16], 3, 1)
            .build()
            .unwrap()
    }

    /// An endless reader that counts the bytes it hands out.
    struct Endless {
        handed_out: usize,
    }

    impl Read for Endless {
        fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
            buf.fill(0);
            self.handed_out += buf.len();
            Ok(buf.len())
        }
    }

    #[test]
    fn read_policy_file_reads_an_exact_blob() {
        let blob = valid();
        let file = TempFile::with("exact", blob.as_bytes());
        let back = read_policy_file(&file.0).unwrap();
        assert_eq!(back.as_bytes(), blob.as_bytes());
        assert_eq!(back.validate(), Ok(()));
    }

    #[cfg(unix)]
    #[test]
    fn read_policy_file_rejects_dev_zero_as_longer_than_a_blob() {
        let e = read_policy_file(Path::new("/dev/zero")).unwrap_err();
        let expected = POLICY_FILE_BYTES;
        assert!(
            matches!(e, PolicyFileError::TooLong { actual: None, expected: n } if n == expected),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            format!("longer than a policy blob ({POLICY_FILE_BYTES} bytes)")
        );
    }

    #[test]
    fn read_policy_blob_reads_at_most_one_byte_past_a_blob_from_an_endless_input() {
        let mut endless = Endless { handed_out: 0 };
        let e = read_policy_blob(&mut endless).unwrap_err();
        assert!(matches!(e, PolicyFileError::TooLong { .. }), "{e:?}");
        assert_eq!(endless.handed_out, POLICY_FILE_BYTES + 1);
    }

    #[test]
    fn read_policy_file_rejects_an_over_long_file_naming_both_sizes() {
        let mut bytes = valid().as_bytes().to_vec();
        bytes.extend_from_slice(&[0; 10]);
        let file = TempFile::with("long", &bytes);
        let e = read_policy_file(&file.0).unwrap_err();
        let actual = POLICY_FILE_BYTES as u64 + 10;
        assert!(
            matches!(e, PolicyFileError::TooLong { actual: Some(a), .. } if a == actual),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            format!("{actual} bytes, longer than a policy blob ({POLICY_FILE_BYTES} bytes)")
        );
    }

    #[test]
    fn read_policy_file_rejects_a_short_file_naming_both_sizes() {
        let file = TempFile::with("short", &valid().as_bytes()[..100]);
        let e = read_policy_file(&file.0).unwrap_err();
        assert!(
            matches!(e, PolicyFileError::TooShort { actual: 100, .. }),
            "{e:?}"
        );
        assert_eq!(
            e.to_string(),
            format!("100 bytes, shorter than a policy blob ({POLICY_FILE_BYTES} bytes)")
        );
        let empty = TempFile::with("empty", &[]);
        assert!(matches!(
            read_policy_file(&empty.0),
            Err(PolicyFileError::TooShort { actual: 0, .. })
        ));
    }

    #[test]
    fn read_policy_file_reports_a_missing_file_as_io() {
        let e = read_policy_file(Path::new("/nonexistent/foresight.blob")).unwrap_err();
        assert!(matches!(&e, PolicyFileError::Io(io) if io.kind() == io::ErrorKind::NotFound));
        assert_eq!(io::Error::from(e).kind(), io::ErrorKind::NotFound);
        let long = io::Error::from(PolicyFileError::TooLong {
            actual: None,
            expected: POLICY_FILE_BYTES,
        });
        assert_eq!(long.kind(), io::ErrorKind::InvalidData);
        assert!(long.to_string().contains("longer than a policy blob"));
    }
}
