//! A memory-bounded LRU of transport operators, owned by whoever needs one (the service's state, an experiment).

use crate::physics::display::DisplayGeometry;
use crate::physics::transport::{EyePosition, TransportError, TransportMatrix, TransportOptions};
use crate::physics::zernike::ZernikeCoefficients;

/// A cache of transport operators, keyed by everything that determines them (display geometry,
/// wavefront, eye position, options), bounded in memory; least recently used entries are evicted first.
pub struct TransportCache {
    inner: std::sync::Mutex<CacheInner>,
}

pub(crate) struct CacheInner {
    capacity_bytes: usize,
    used_bytes: usize,
    tick: u64,
    entries: std::collections::HashMap<String, (std::sync::Arc<TransportMatrix>, u64)>,
    hits: u64,
    misses: u64,
}

impl TransportCache {
    /// A cache that keeps nothing: every request builds its operator (benchmarks, one-off commands).
    pub fn disabled() -> Self {
        Self::new(0)
    }

    /// An empty cache holding at most `capacity_bytes` of operators.
    pub fn new(capacity_bytes: usize) -> Self {
        Self {
            inner: std::sync::Mutex::new(CacheInner {
                capacity_bytes,
                used_bytes: 0,
                tick: 0,
                entries: Default::default(),
                hits: 0,
                misses: 0,
            }),
        }
    }

    /// Changes the memory bound (0 disables caching), evicting as needed.
    pub fn set_capacity_bytes(&self, capacity_bytes: usize) {
        let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        g.capacity_bytes = capacity_bytes;
        Self::evict(&mut g, 0);
    }

    /// (hits, misses, bytes held).
    pub fn stats(&self) -> (u64, u64, usize) {
        let g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        (g.hits, g.misses, g.used_bytes)
    }

    fn evict(g: &mut CacheInner, incoming: usize) {
        while g.used_bytes + incoming > g.capacity_bytes && !g.entries.is_empty() {
            let oldest = g.entries.iter().min_by_key(|(_, (_, t))| *t).map(|(k, _)| k.clone());
            if let Some(k) = oldest {
                if let Some((m, _)) = g.entries.remove(&k) {
                    g.used_bytes -= m.memory_bytes();
                }
            }
        }
    }

    /// The operator for these inputs, built (outside the lock) if it is not cached.
    pub fn get_or_build(
        &self,
        display: &DisplayGeometry,
        wavefront: &ZernikeCoefficients,
        eye: EyePosition,
        options: &TransportOptions,
    ) -> Result<std::sync::Arc<TransportMatrix>, TransportError> {
        let key = Self::key(display, wavefront, eye, options).to_string();
        self.get_or_insert_with(key, || TransportMatrix::build(display, wavefront, eye, options))
    }

    /// Everything that determines one build's operator, as a cache key.
    pub fn key(
        display: &DisplayGeometry,
        wavefront: &ZernikeCoefficients,
        eye: EyePosition,
        options: &TransportOptions,
    ) -> serde_json::Value {
        let mut key = serde_json::json!({
            "display": display, "wavefront": wavefront, "eye": eye,
            "sub_rays": options.sub_rays, "seed": options.seed,
            "oversample": options.retina_oversample, "terms": options.derivative_terms, "wave": options.wave,
            "sequence": options.sequence,
        });
        if options.tracked {
            key["tracked"] = serde_json::Value::Bool(true);
        }
        key
    }

    /// The operator cached under `key`, or `build`'s (built outside the lock, then cached): for operators
    /// assembled from several builds (a band's wavelengths mixed), keyed by everything that determines them.
    pub fn get_or_insert_with(
        &self,
        key: String,
        build: impl FnOnce() -> Result<TransportMatrix, TransportError>,
    ) -> Result<std::sync::Arc<TransportMatrix>, TransportError> {
        {
            let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
            g.tick += 1;
            let tick = g.tick;
            if let Some((m, t)) = g.entries.get_mut(&key) {
                *t = tick;
                let m = m.clone();
                g.hits += 1;
                return Ok(m);
            }
            g.misses += 1;
        }
        let m = std::sync::Arc::new(build()?);
        let size = m.memory_bytes();
        let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        if size <= g.capacity_bytes {
            Self::evict(&mut g, size);
            g.tick += 1;
            let tick = g.tick;
            if g.entries.insert(key, (m.clone(), tick)).is_none() {
                g.used_bytes += size;
            }
        }
        Ok(m)
    }
}

impl Default for TransportCache {
    /// A cache of [`DEFAULT_CAPACITY_BYTES`].
    fn default() -> Self {
        Self::new(DEFAULT_CAPACITY_BYTES)
    }
}

/// Memory bound of [`TransportCache::default`]: 512 MiB, a few dozen paper-preset operators.
pub const DEFAULT_CAPACITY_BYTES: usize = 512 << 20;
