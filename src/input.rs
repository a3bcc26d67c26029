//! Reading input files with a size limit: a file (or a device such as `/dev/zero`) larger
//! than what its kind can sensibly be is refused after reading at most the limit, never read
//! until memory runs out.

use std::io::Read;
use std::path::Path;

/// Largest OBJ file read (about 20 million triangles of text).
pub const MAX_OBJ_BYTES: u64 = 2 << 30;
/// Largest MTL file read.
pub const MAX_MTL_BYTES: u64 = 64 << 20;
/// Largest JSON input (camera, lights) read.
pub const MAX_JSON_BYTES: u64 = 16 << 20;

/// Why an input file could not be read.
#[derive(Debug, thiserror::Error)]
pub enum InputError {
    /// The file does not exist.
    #[error("{path}: file not found")]
    NotFound {
        /// The path.
        path: String,
    },
    /// Reading failed.
    #[error("{path}: {source}")]
    Io {
        /// The path.
        path: String,
        /// The error.
        source: std::io::Error,
    },
    /// The file is larger than its kind may be.
    #[error("{path}: larger than {limit} bytes, the most {what} may be (is it the right file?)")]
    TooLarge {
        /// The path.
        path: String,
        /// The limit in bytes.
        limit: u64,
        /// What the file was read as, with its article ("an OBJ file").
        what: &'static str,
    },
}

/// The bytes of `path`, refused with [`InputError::TooLarge`] past `limit` bytes (`what`
/// names the kind of file in the message). The size is checked before reading where the
/// file system knows it, and the read stops one byte past the limit where it does not.
pub fn read_limited(path: &Path, limit: u64, what: &'static str) -> Result<Vec<u8>, InputError> {
    let label = || path.display().to_string();
    let io = |source: std::io::Error| match source.kind() {
        std::io::ErrorKind::NotFound => InputError::NotFound { path: label() },
        _ => InputError::Io { path: label(), source },
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let too_large = || InputError::TooLarge { path: label(), limit, what };
    let known = file.metadata().map_err(io)?.len();
    if known > limit {
        return Err(too_large());
    }
    let mut bytes = Vec::with_capacity(known as usize);
    file.take(limit + 1).read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() as u64 > limit {
        return Err(too_large());
    }
    Ok(bytes)
}

/// [`read_limited`] as UTF-8 text.
pub fn read_text_limited(path: &Path, limit: u64, what: &'static str) -> Result<String, InputError> {
    let bytes = read_limited(path, limit, what)?;
    String::from_utf8(bytes).map_err(|e| InputError::Io {
        path: path.display().to_string(),
        source: std::io::Error::new(std::io::ErrorKind::InvalidData, e),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_device_without_end_is_refused_at_the_limit() {
        let zero = Path::new("/dev/zero");
        if !zero.exists() {
            return;
        }
        let e = read_limited(zero, 1 << 20, "a test file").unwrap_err();
        assert!(matches!(e, InputError::TooLarge { limit: 1048576, .. }), "{e}");
        assert!(e.to_string().contains("larger than 1048576 bytes"), "{e}");
    }

    #[test]
    fn files_within_the_limit_are_read_whole() {
        let p = std::env::temp_dir().join(format!("voxray-input-{}.txt", std::process::id()));
        std::fs::write(&p, b"12345").unwrap();
        assert_eq!(read_limited(&p, 5, "a test file").unwrap(), b"12345");
        assert!(matches!(read_limited(&p, 4, "a test file"), Err(InputError::TooLarge { .. })));
        std::fs::remove_file(&p).unwrap();
        assert!(matches!(read_limited(&p, 4, "a test file"), Err(InputError::NotFound { .. })));
    }
}
