//! A process-wide store of shared values bounded by the bytes they hold, oldest out first: the sampled kernels'
//! ray bundles and the quadrature's tables.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard};

/// Values by key, at most `capacity` bytes of them; a value larger than that is made but not kept.
pub(super) struct ByteBoundedCache<T> {
    inner: Mutex<Inner<T>>,
    capacity: usize,
}

struct Inner<T> {
    map: HashMap<String, Arc<T>>,
    order: VecDeque<String>,
    bytes: usize,
}

impl<T> ByteBoundedCache<T> {
    pub(super) fn new(capacity: usize) -> Self {
        Self {
            inner: Mutex::new(Inner {
                map: HashMap::new(),
                order: VecDeque::new(),
                bytes: 0,
            }),
            capacity,
        }
    }

    fn lock(&self) -> MutexGuard<'_, Inner<T>> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The value under `key`, or `make()`'s (made outside the lock), kept while it fits; `bytes` measures one.
    pub(super) fn get_or_make(&self, key: String, make: impl FnOnce() -> T, bytes: impl Fn(&T) -> usize) -> Arc<T> {
        if let Some(v) = self.lock().map.get(&key) {
            return v.clone();
        }
        let value = Arc::new(make());
        let size = bytes(&value);
        let mut c = self.lock();
        if !c.map.contains_key(&key) && size <= self.capacity {
            c.bytes += size;
            c.map.insert(key.clone(), value.clone());
            c.order.push_back(key);
            while c.bytes > self.capacity {
                let Some(old) = c.order.pop_front() else { break };
                if let Some(v) = c.map.remove(&old) {
                    c.bytes -= bytes(&v);
                }
            }
        }
        value
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A value is made once and shared; the oldest go first once the bytes exceed the bound; a value larger than
    /// the bound is made each time and never kept.
    #[test]
    fn values_are_shared_and_the_oldest_go_first() {
        let cache = ByteBoundedCache::<Vec<u8>>::new(10);
        let made = std::cell::Cell::new(0);
        let get = |key: &str, len: usize| {
            cache.get_or_make(
                key.to_string(),
                || {
                    made.set(made.get() + 1);
                    vec![0; len]
                },
                Vec::len,
            )
        };
        let a = get("a", 4);
        assert!(Arc::ptr_eq(&a, &get("a", 4)));
        get("b", 4);
        get("c", 4); // 12 bytes: "a" goes.
        assert_eq!(made.get(), 3);
        get("b", 4);
        assert_eq!(made.get(), 3, "b is kept");
        get("a", 4);
        assert_eq!(made.get(), 4, "a was dropped");
        get("big", 11);
        get("big", 11);
        assert_eq!(made.get(), 6, "a value beyond the bound is never kept");
    }
}
