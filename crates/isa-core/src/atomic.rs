//! Atomic file writes, done once for every writer (models, training sets, the CLI's outputs).
//!
//! A file is written to a temporary name in the target's folder, synced, renamed onto the
//! target and the folder synced, so a reader sees the old file or the new one, whole. The
//! temporary name is unique per write (the `tempfile` crate), not derived from the target's
//! extension or the process id, so two threads writing `a.isat` and `a.bak`, or two writers of
//! one path, never share it; of concurrent writers of one path the last rename wins, whole.
//!
//! Naming (shared with Python's `isa.atomic`): `.{target name}.isa-tmp-{random}{extension}`.
//! The writer holds an exclusive lock (`flock`) on its temporary file until the rename, which
//! tells a live write from the leftover of a killed one: [`clean_stale`] and
//! [`clean_stale_in`] remove only the temporary files of this naming that nobody holds, and run
//! on the next write of the target and when a model or training set is opened.

use std::ffi::OsStr;
use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::Path;

use crate::error::{IsaError, Result};

/// What every temporary name holds after the target's name.
pub const TEMP_MARK: &str = ".isa-tmp-";

fn io_err(path: &Path) -> impl Fn(io::Error) -> IsaError + '_ {
    move |source| IsaError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// The folder (`.` for a bare name) and the file name of `path`.
fn split(path: &Path) -> Option<(&Path, &OsStr)> {
    let name = path.file_name()?;
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    Some((dir, name))
}

fn temp_prefix(name: &OsStr) -> String {
    format!(".{}{TEMP_MARK}", name.to_string_lossy())
}

/// Whether `path` still names the file open as `f` (a cleaner may have removed it between
/// creation and locking).
fn still_named(path: &Path, f: &File) -> io::Result<bool> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let (a, b) = (fs::metadata(path)?, f.metadata()?);
        Ok(a.dev() == b.dev() && a.ino() == b.ino())
    }
    #[cfg(not(unix))]
    {
        let _ = f;
        Ok(path.exists())
    }
}

/// A new temporary file for `name` in `dir`, locked by this writer.
fn locked_temp(dir: &Path, name: &OsStr) -> io::Result<tempfile::NamedTempFile> {
    let prefix = temp_prefix(name);
    let ext = Path::new(name)
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(&ext);
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        // As File::create would (the umask applies), not tempfile's private 0600.
        builder.permissions(fs::Permissions::from_mode(0o666));
    }
    loop {
        let tmp = builder.tempfile_in(dir)?;
        tmp.as_file().lock()?;
        match still_named(tmp.path(), tmp.as_file()) {
            Ok(true) => return Ok(tmp),
            // Removed by a cleaner in the instant before the lock: take another name.
            Ok(false) => continue,
            Err(e) if e.kind() == io::ErrorKind::NotFound => continue,
            Err(e) => return Err(e),
        }
    }
}

/// Writes `path` whole or not at all: `write` fills a temporary file in the same folder
/// (buffered), which is synced and renamed onto `path`, then the folder is synced. Stale
/// temporary files of `path` are removed first. Errors are [`IsaError::Io`] naming `path`;
/// on error nothing is left behind and `path` is untouched.
pub fn write_with(path: &Path, write: impl FnOnce(&mut dyn Write) -> io::Result<()>) -> Result<()> {
    let err = io_err(path);
    let (dir, name) = split(path)
        .ok_or_else(|| IsaError::InvalidInput(format!("path {} names no file", path.display())))?;
    clean_stale(path);
    let tmp = locked_temp(dir, name).map_err(&err)?;
    let mut w = BufWriter::new(tmp);
    write(&mut w).map_err(&err)?;
    let tmp = w.into_inner().map_err(|e| err(e.into_error()))?;
    tmp.as_file().sync_all().map_err(&err)?;
    // The lock goes with the file handle, after the rename.
    let _file = tmp.persist(path).map_err(|e| err(e.error))?;
    sync_dir(dir);
    Ok(())
}

/// [`write_with`] of a byte string.
pub fn write_bytes(path: &Path, bytes: &[u8]) -> Result<()> {
    write_with(path, |w| w.write_all(bytes))
}

/// Makes a rename durable. Best effort: not every platform or file system can sync a folder.
fn sync_dir(dir: &Path) {
    #[cfg(unix)]
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
    #[cfg(not(unix))]
    let _ = dir;
}

/// Removes the stale temporary files of `path` (left by a killed writer). Never fails: a file
/// that cannot be inspected or removed is left.
pub fn clean_stale(path: &Path) {
    if let Some((dir, name)) = split(path) {
        let prefix = temp_prefix(name);
        clean_matching(dir, |n| n.starts_with(&prefix));
    }
}

/// Removes every stale isa temporary file in `dir` (for writers of many files).
pub fn clean_stale_in(dir: &Path) {
    clean_matching(dir, |n| n.starts_with('.') && n.contains(TEMP_MARK));
}

fn clean_matching(dir: &Path, ours: impl Fn(&str) -> bool) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let name = e.file_name();
        if !name.to_str().is_some_and(&ours) {
            continue;
        }
        let p = e.path();
        let Ok(f) = File::open(&p) else { continue };
        // Held: a live writer's. Free: its writer is gone (a rename would have taken the name).
        if f.try_lock().is_ok() && still_named(&p, &f).unwrap_or(false) {
            let _ = fs::remove_file(&p);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;
    use std::sync::Arc;

    fn scratch(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("isa-atomic-{tag}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        fs::create_dir_all(&d).unwrap();
        d
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    /// The case of issue 20: `set.isat` and `set.bak` from two threads of one process shared
    /// one temporary name (`set.tmp<pid>`), so one file got the other's data.
    #[test]
    fn two_threads_writing_two_paths_never_swap_data() {
        let dir = Arc::new(scratch("swap"));
        let writer = |name: &'static str, byte: u8| {
            let dir = dir.clone();
            std::thread::spawn(move || {
                let body = vec![byte; 64 * 1024];
                for _ in 0..150 {
                    write_bytes(&dir.join(name), &body).unwrap();
                    assert_eq!(fs::read(dir.join(name)).unwrap(), body, "{name}");
                }
            })
        };
        let (a, b) = (writer("set.isat", b'a'), writer("set.bak", b'b'));
        a.join().unwrap();
        b.join().unwrap();
        assert_eq!(names(&dir), ["set.bak", "set.isat"]);
        fs::remove_dir_all(&*dir).unwrap();
    }

    #[test]
    fn concurrent_saves_to_one_path_all_succeed_and_the_last_wins_whole() {
        let dir = scratch("one");
        let path = Arc::new(dir.join("m.isaf"));
        let threads: Vec<_> = (0..4u8)
            .map(|t| {
                let path = path.clone();
                std::thread::spawn(move || {
                    for i in 0..100u8 {
                        let body = vec![t.wrapping_mul(31).wrapping_add(i); 4096 + i as usize];
                        write_bytes(&path, &body).unwrap();
                    }
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }
        // Whole: one writer's last body (each body is one repeated byte of its own length).
        let got = fs::read(&*path).unwrap();
        let i = got.len() - 4096;
        assert!(i < 100 && got.iter().all(|&b| b == got[0]));
        assert!((0..4u8).any(|t| t.wrapping_mul(31).wrapping_add(i as u8) == got[0]));
        assert_eq!(names(&dir), ["m.isaf"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn stale_temps_go_on_the_next_write_live_ones_stay() {
        let dir = scratch("stale");
        let path = dir.join("m.isaf");
        // A killed writer's leftover: our naming, unlocked.
        let stale = dir.join(format!(".m.isaf{TEMP_MARK}dead01.isaf"));
        fs::write(&stale, b"half").unwrap();
        // A live writer's: locked.
        let live = locked_temp(&dir, OsStr::new("m.isaf")).unwrap();
        // Not ours: kept.
        fs::write(dir.join(".m.isaf.tmp"), b"x").unwrap();
        write_bytes(&path, b"new").unwrap();
        assert!(!stale.exists());
        assert!(live.path().exists());
        assert!(dir.join(".m.isaf.tmp").exists());
        let live_path = live.path().to_path_buf();
        drop(live);
        assert!(!live_path.exists(), "tempfile removes its own file on drop");
        fs::write(&stale, b"half").unwrap();
        fs::write(dir.join(format!(".other.png{TEMP_MARK}x.png")), b"").unwrap();
        clean_stale_in(&dir);
        assert_eq!(names(&dir), [".m.isaf.tmp", "m.isaf"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_failed_write_leaves_the_target_and_no_temp() {
        let dir = scratch("fail");
        let path = dir.join("m.isaf");
        fs::write(&path, b"old").unwrap();
        let e = write_with(&path, |w| {
            w.write_all(b"partial")?;
            Err(io::Error::other("disk full"))
        })
        .unwrap_err();
        assert!(
            e.to_string().contains("m.isaf") && e.to_string().contains("disk full"),
            "{e}"
        );
        assert_eq!(fs::read(&path).unwrap(), b"old");
        assert_eq!(names(&dir), ["m.isaf"]);
        let missing = dir.join("no/such/dir/m.isaf");
        assert!(matches!(
            write_bytes(&missing, b"x"),
            Err(IsaError::Io { .. })
        ));
        fs::remove_dir_all(&dir).unwrap();
    }
}
