//! What a caller that registers many pairs keeps in memory between them: content hashes of
//! input files (the stage keys hash the same depth, colour and model files again and again)
//! and loaded VFM models (bench registers many pairs with one model). A [`Memo`] is owned by
//! its caller (the inspector's worker, one `cgenreg bench` or study run, one registration)
//! and handed down through the stage context and the key functions; it is bounded ([`Lru`]),
//! and dropping the owner frees it. Nothing here is process-global.

use crate::error::{Error, Result};
use crate::vfm::{PairModel, PerImageModel};
use std::borrow::Borrow;
use std::collections::HashMap;
use std::hash::Hash;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// A map of at most `cap` entries: inserting a new key into a full map drops the least
/// recently used one (a lookup with [`Lru::get`] counts as a use).
#[derive(Debug, Clone)]
pub struct Lru<K, V> {
    cap: usize,
    clock: u64,
    map: HashMap<K, (V, u64)>,
}

impl<K: Eq + Hash + Clone, V> Lru<K, V> {
    /// An empty map holding at most `cap` entries (at least 1).
    pub fn new(cap: usize) -> Self {
        Lru {
            cap: cap.max(1),
            clock: 0,
            map: HashMap::new(),
        }
    }

    fn tick(&mut self) -> u64 {
        self.clock += 1;
        self.clock
    }

    /// The value of `k`, marked as just used.
    pub fn get<Q>(&mut self, k: &Q) -> Option<&V>
    where
        K: Borrow<Q>,
        Q: Hash + Eq + ?Sized,
    {
        let t = self.tick();
        self.map.get_mut(k).map(|(v, used)| {
            *used = t;
            &*v
        })
    }

    /// The value of `k`, without marking it used.
    pub fn peek<Q>(&self, k: &Q) -> Option<&V>
    where
        K: Borrow<Q>,
        Q: Hash + Eq + ?Sized,
    {
        self.map.get(k).map(|(v, _)| v)
    }

    pub fn contains_key<Q>(&self, k: &Q) -> bool
    where
        K: Borrow<Q>,
        Q: Hash + Eq + ?Sized,
    {
        self.map.contains_key(k)
    }

    /// Insert (or replace) `k`, marked as just used; returns the entry dropped to make room.
    pub fn insert(&mut self, k: K, v: V) -> Option<(K, V)> {
        let t = self.tick();
        let mut evicted = None;
        if !self.map.contains_key(&k) && self.map.len() >= self.cap {
            let oldest = self
                .map
                .iter()
                .min_by_key(|(_, (_, used))| *used)
                .map(|(k, _)| k.clone());
            if let Some(o) = oldest {
                evicted = self.map.remove(&o).map(|(v, _)| (o, v));
            }
        }
        self.map.insert(k, (v, t));
        evicted
    }

    pub fn remove<Q>(&mut self, k: &Q) -> Option<V>
    where
        K: Borrow<Q>,
        Q: Hash + Eq + ?Sized,
    {
        self.map.remove(k).map(|(v, _)| v)
    }

    pub fn len(&self) -> usize {
        self.map.len()
    }

    pub fn is_empty(&self) -> bool {
        self.map.is_empty()
    }
}

/// Files whose content hash a [`Memo`] remembers (a pair's 2L depth frames, 2L colour frames
/// and the model file, for several pairs).
pub const FILE_HASHES: usize = 4096;
/// Per-image VFM models a [`Memo`] keeps loaded (XFeat, DISK, ALIKE side by side).
pub const MODELS: usize = 4;
/// Pair-conditioned VFM models a [`Memo`] keeps loaded (MASt3R is large: one, and a spare).
pub const PAIR_MODELS: usize = 2;

/// One scan's depth views a [`Memo`] keeps decoded for the `visibility` fusion (every pair of a
/// scan compares poses in the same 2 x L frames): a few scans, each L frames (50 frames at
/// 960x704 are 68 MB).
pub const DEPTH_VIEW_SETS: usize = 4;

/// (length, modification time): a file rewritten in place changes one of them.
type Stamp = (u64, std::time::SystemTime);

/// A scan's depth frames, decoded, with the stamps of the files they were read from.
type DepthSet = (Vec<Stamp>, Arc<Vec<crate::io::depth_png::DepthImage>>);

/// The in-memory state of one caller; see the module doc. Shared by reference (the stages
/// run on rayon threads), so each part sits behind its own lock.
pub struct Memo {
    files: Mutex<Lru<PathBuf, (Stamp, String)>>,
    models: Mutex<Lru<String, Arc<dyn PerImageModel>>>,
    pair_models: Mutex<Lru<String, Arc<dyn PairModel>>>,
    /// Keyed by the frames' paths, in order.
    depth_views: Mutex<Lru<Vec<PathBuf>, DepthSet>>,
}

impl Default for Memo {
    fn default() -> Self {
        Memo::with_capacity(FILE_HASHES, MODELS, PAIR_MODELS)
    }
}

/// How many entries each part of a [`Memo`] holds now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MemoSizes {
    pub file_hashes: usize,
    pub models: usize,
    pub pair_models: usize,
    pub depth_view_sets: usize,
}

impl Memo {
    pub fn with_capacity(file_hashes: usize, models: usize, pair_models: usize) -> Self {
        Memo {
            files: Mutex::new(Lru::new(file_hashes)),
            models: Mutex::new(Lru::new(models)),
            pair_models: Mutex::new(Lru::new(pair_models)),
            depth_views: Mutex::new(Lru::new(DEPTH_VIEW_SETS)),
        }
    }

    /// The depth frames at `paths` (in that order), decoded by `read` or taken from the memo
    /// when every file still has the length and modification time it was read with. Files
    /// without a modification time are read every time.
    pub fn depth_views(
        &self,
        paths: &[PathBuf],
        read: impl FnOnce() -> Result<Vec<crate::io::depth_png::DepthImage>>,
    ) -> Result<Arc<Vec<crate::io::depth_png::DepthImage>>> {
        let stamps: Option<Vec<Stamp>> = paths
            .iter()
            .map(|p| {
                let m = std::fs::metadata(p).ok()?;
                Some((m.len(), m.modified().ok()?))
            })
            .collect();
        let Some(stamps) = stamps else {
            return read().map(Arc::new);
        };
        if let Ok(mut m) = self.depth_views.lock() {
            if let Some((s, views)) = m.get(paths) {
                if *s == stamps {
                    return Ok(views.clone());
                }
            }
        }
        let views = Arc::new(read()?);
        if let Ok(mut m) = self.depth_views.lock() {
            m.insert(paths.to_vec(), (stamps, views.clone()));
        }
        Ok(views)
    }

    pub fn sizes(&self) -> MemoSizes {
        MemoSizes {
            file_hashes: self.files.lock().map(|g| g.len()).unwrap_or(0),
            models: self.models.lock().map(|g| g.len()).unwrap_or(0),
            pair_models: self.pair_models.lock().map(|g| g.len()).unwrap_or(0),
            depth_view_sets: self.depth_views.lock().map(|g| g.len()).unwrap_or(0),
        }
    }

    /// [`hash_file`](crate::cache::hash_file) remembered by (path, length,
    /// modification time). A file without a modification time cannot be told apart from a
    /// rewrite, so it is hashed every time.
    pub fn hash_file(&self, path: &Path) -> Result<String> {
        let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
        let Ok(modified) = meta.modified() else {
            return crate::cache::hash_file(path);
        };
        let stamp: Stamp = (meta.len(), modified);
        if let Ok(mut m) = self.files.lock() {
            if let Some((s, h)) = m.get(path) {
                if *s == stamp {
                    return Ok(h.clone());
                }
            }
        }
        // hashed outside the lock: the key functions hash many files in parallel
        let h = crate::cache::hash_file(path)?;
        if let Ok(mut m) = self.files.lock() {
            m.insert(path.to_path_buf(), (stamp, h.clone()));
        }
        Ok(h)
    }

    /// The per-image model with cache id `id` (`vfm_id`: name and content hash), loaded by
    /// `load` on the first request.
    pub(crate) fn per_image_model(
        &self,
        id: &str,
        load: impl FnOnce() -> Result<Arc<dyn PerImageModel>>,
    ) -> Result<Arc<dyn PerImageModel>> {
        memoized(&self.models, id, load)
    }

    /// The pair-conditioned model with cache id `id`, loaded by `load` on the first request.
    pub(crate) fn pair_model(
        &self,
        id: &str,
        load: impl FnOnce() -> Result<Arc<dyn PairModel>>,
    ) -> Result<Arc<dyn PairModel>> {
        memoized(&self.pair_models, id, load)
    }
}

/// The model under `id`, or `load` (outside the lock: loading takes seconds, and another
/// thread hashing files must not wait) then kept.
fn memoized<T: ?Sized>(
    models: &Mutex<Lru<String, Arc<T>>>,
    id: &str,
    load: impl FnOnce() -> Result<Arc<T>>,
) -> Result<Arc<T>> {
    let poisoned = || Error::Invalid("VFM model memo poisoned by an earlier panic".into());
    if let Some(m) = models.lock().map_err(|_| poisoned())?.get(id) {
        return Ok(m.clone());
    }
    let m = load()?;
    models
        .lock()
        .map_err(|_| poisoned())?
        .insert(id.to_string(), m.clone());
    Ok(m)
}

impl super::inputs::DepthViewStore for Memo {
    fn depth_views(
        &self,
        paths: &[PathBuf],
        read: &dyn Fn() -> Result<Vec<crate::io::depth_png::DepthImage>>,
    ) -> Result<Arc<Vec<crate::io::depth_png::DepthImage>>> {
        Memo::depth_views(self, paths, read)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Against a brute-force model: a list in order of last use, truncated to `cap`.
        #[test]
        fn lru_keeps_the_most_recently_used(
            cap in 1usize..6,
            ops in proptest::collection::vec((0u8..3, 0u8..10), 0..200),
        ) {
            let mut lru = Lru::new(cap);
            let mut model: Vec<(u8, u32)> = Vec::new(); // most recent last
            for (i, (op, k)) in ops.into_iter().enumerate() {
                let v = i as u32;
                match op {
                    0 => {
                        let evicted = lru.insert(k, v);
                        let expect = if model.iter().any(|(m, _)| *m == k) {
                            model.retain(|(m, _)| *m != k);
                            None
                        } else if model.len() >= cap {
                            Some(model.remove(0))
                        } else {
                            None
                        };
                        model.push((k, v));
                        prop_assert_eq!(evicted, expect);
                    }
                    1 => {
                        let got = lru.get(&k).copied();
                        let pos = model.iter().position(|(m, _)| *m == k);
                        prop_assert_eq!(got, pos.map(|p| model[p].1));
                        if let Some(p) = pos {
                            let e = model.remove(p);
                            model.push(e);
                        }
                    }
                    _ => {
                        let got = lru.remove(&k);
                        let pos = model.iter().position(|(m, _)| *m == k);
                        prop_assert_eq!(got, pos.map(|p| model.remove(p).1));
                    }
                }
                prop_assert!(lru.len() <= cap);
                prop_assert_eq!(lru.len(), model.len());
            }
        }
    }

    #[test]
    fn file_hashes_follow_rewrites_and_stay_bounded() {
        let dir = tempfile::tempdir().unwrap();
        let memo = Memo::with_capacity(2, 1, 1);
        let p = dir.path().join("a.bin");
        std::fs::write(&p, b"one").unwrap();
        let a = memo.hash_file(&p).unwrap();
        assert_eq!(a, crate::cache::hash_file(&p).unwrap());
        assert_eq!(memo.hash_file(&p).unwrap(), a);
        // a rewrite with other content of the same length (a later time) is hashed again
        let f = std::fs::File::options().write(true).open(&p).unwrap();
        std::io::Write::write_all(&mut &f, b"two").unwrap();
        let later = std::time::SystemTime::now() + std::time::Duration::from_secs(5);
        f.set_modified(later).unwrap();
        drop(f);
        let b = memo.hash_file(&p).unwrap();
        assert_ne!(a, b);
        assert_eq!(b, crate::cache::hash_file(&p).unwrap());
        // and one with another length
        std::fs::write(&p, b"three").unwrap();
        assert_eq!(
            memo.hash_file(&p).unwrap(),
            crate::cache::hash_file(&p).unwrap()
        );
        for i in 0..5 {
            let q = dir.path().join(format!("{i}.bin"));
            std::fs::write(&q, [i as u8]).unwrap();
            memo.hash_file(&q).unwrap();
        }
        assert_eq!(memo.sizes().file_hashes, 2);
        let e = memo.hash_file(&dir.path().join("missing")).unwrap_err();
        assert!(e.to_string().contains("missing"), "{e}");
    }

    #[test]
    fn a_failed_model_load_is_not_kept() {
        let memo = Memo::with_capacity(1, 1, 1);
        let e = memo
            .per_image_model("m@0", || Err(Error::Invalid("no such model".into())))
            .err()
            .unwrap();
        assert!(e.to_string().contains("no such model"));
        assert_eq!(memo.sizes().models, 0);
    }
}
