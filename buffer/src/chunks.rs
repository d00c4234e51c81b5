//! A vector kept in shared chunks: a clone shares every chunk, and a write to a chunk that a
//! clone still holds copies that chunk alone (copy on write). A consistent copy of a large
//! ring (its transitions, generations and priorities), which a background snapshot takes,
//! then costs its chunks, not its items.

use std::ops::Index;
use std::sync::Arc;

use serde::ser::SerializeSeq;
use serde::{Serialize, Serializer};

/// Items per chunk: 4,096 transitions are about 256 KB, copied at most once per snapshot.
const CHUNK: usize = 4096;

#[derive(Clone, Debug)]
pub(crate) struct SharedChunks<T> {
    chunks: Vec<Arc<Vec<T>>>,
    len: usize,
}

impl<T> Default for SharedChunks<T> {
    fn default() -> Self {
        Self {
            chunks: Vec::new(),
            len: 0,
        }
    }
}

impl<T: Clone> SharedChunks<T> {
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    pub(crate) fn push(&mut self, item: T) {
        if self.len.is_multiple_of(CHUNK) {
            self.chunks.push(Arc::new(Vec::with_capacity(CHUNK)));
        }
        let last = self.chunks.last_mut().expect("a chunk was just made");
        Arc::make_mut(last).push(item);
        self.len += 1;
    }

    /// Replaces item `i`, copying its chunk first if a clone shares it.
    ///
    /// # Panics
    /// If `i >= len`.
    pub(crate) fn set(&mut self, i: usize, item: T) {
        assert!(i < self.len, "item {i} of {}", self.len);
        Arc::make_mut(&mut self.chunks[i / CHUNK])[i % CHUNK] = item;
    }

    pub(crate) fn get(&self, i: usize) -> Option<&T> {
        (i < self.len).then(|| &self[i])
    }

    pub(crate) fn iter(&self) -> impl Iterator<Item = &T> {
        self.chunks.iter().flat_map(|chunk| chunk.iter())
    }
}

/// As a sequence of its items.
impl<T: Clone + Serialize> Serialize for SharedChunks<T> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        // Its length first: a flattened iterator cannot tell it, and postcard needs it.
        let mut seq = serializer.serialize_seq(Some(self.len))?;
        self.iter()
            .try_for_each(|item| seq.serialize_element(item))?;
        seq.end()
    }
}

impl<T> Index<usize> for SharedChunks<T> {
    type Output = T;

    fn index(&self, i: usize) -> &T {
        assert!(i < self.len, "item {i} of {}", self.len);
        &self.chunks[i / CHUNK][i % CHUNK]
    }
}

impl<T: Clone> FromIterator<T> for SharedChunks<T> {
    fn from_iter<I: IntoIterator<Item = T>>(items: I) -> Self {
        let mut chunks = Self::default();
        items.into_iter().for_each(|item| chunks.push(item));
        chunks
    }
}

impl<T: Clone + PartialEq> PartialEq for SharedChunks<T> {
    fn eq(&self, other: &Self) -> bool {
        self.len == other.len && self.iter().eq(other.iter())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_clone_keeps_what_it_saw_while_the_original_changes() {
        let mut items: SharedChunks<u32> = (0..3 * CHUNK as u32 + 5).collect();
        let copy = items.clone();
        assert!(Arc::ptr_eq(&items.chunks[1], &copy.chunks[1]), "shared");
        items.set(CHUNK + 7, 99);
        items.push(7);
        assert_eq!(items[CHUNK + 7], 99);
        assert_eq!(copy[CHUNK + 7], CHUNK as u32 + 7);
        assert_eq!((items.len(), copy.len()), (3 * CHUNK + 6, 3 * CHUNK + 5));
        // Only the chunk written was copied.
        assert!(!Arc::ptr_eq(&items.chunks[1], &copy.chunks[1]));
        assert!(Arc::ptr_eq(&items.chunks[0], &copy.chunks[0]));
        assert!(Arc::ptr_eq(&items.chunks[2], &copy.chunks[2]));
        assert_eq!(copy.iter().copied().max(), Some(3 * CHUNK as u32 + 4));
        assert_ne!(items, copy);
        assert_eq!(
            (items.get(3 * CHUNK + 5), items.get(3 * CHUNK + 6)),
            (Some(&7), None)
        );
    }
}
