//! Helpers for this crate's tests (unit and integration); not part of the API.

use std::ffi::OsStr;
use std::path::{Path, PathBuf};

/// A directory in the system's temp directory for one test, named after the test and this
/// process: empty when made, removed with what the test wrote when dropped. When the test
/// fails (the drop runs while panicking) it is kept, and its path printed, to look into.
#[derive(Debug)]
pub struct TempDir(PathBuf);

impl TempDir {
    /// Makes `<temp>/coherent-<name>-<pid>` afresh.
    pub fn new(name: &str) -> TempDir {
        let dir = std::env::temp_dir().join(format!("coherent-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("make a temp dir");
        TempDir(dir)
    }

    /// The directory's path.
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl std::ops::Deref for TempDir {
    type Target = Path;

    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for TempDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<OsStr> for TempDir {
    fn as_ref(&self) -> &OsStr {
        self.0.as_os_str()
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("kept {} (the test failed)", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::TempDir;

    #[test]
    fn a_temp_dir_is_removed_when_dropped_and_kept_when_its_test_fails() {
        let dir = TempDir::new("testing-drop");
        std::fs::write(dir.join("a.txt"), "a").expect("write");
        let path = dir.to_path_buf();
        drop(dir);
        assert!(!path.exists());
        let kept = std::panic::catch_unwind(|| {
            let dir = TempDir::new("testing-kept");
            let path = dir.to_path_buf();
            std::panic::panic_any(path);
        })
        .expect_err("panicked");
        let path = kept.downcast::<std::path::PathBuf>().expect("path");
        assert!(path.exists());
        std::fs::remove_dir_all(*path).expect("remove");
    }
}
