//! [`Bounded`]: the fixed-capacity queue every stage hands work through.

/// A FIFO whose capacity is fixed when it is created (at executor start-up). Pushing into a full
/// queue fails instead of growing, so the real-time path never allocates.
#[derive(Debug, Clone)]
pub struct Bounded<T> {
    items: Vec<T>,
    cap: usize,
    overflows: u64,
}

/// A push into a full [`Bounded`] queue.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("queue full ({capacity} entries)")]
pub struct Full {
    /// The queue's capacity.
    pub capacity: usize,
}

impl<T> Bounded<T> {
    /// An empty queue holding at most `capacity` items (allocated now, never again).
    pub fn with_capacity(capacity: usize) -> Self {
        Self {
            items: Vec::with_capacity(capacity),
            cap: capacity,
            overflows: 0,
        }
    }

    /// Appends `item`, or counts an overflow and returns [`Full`].
    #[inline]
    pub fn push(&mut self, item: T) -> Result<(), Full> {
        if self.items.len() >= self.cap {
            self.overflows += 1;
            return Err(Full { capacity: self.cap });
        }
        self.items.push(item);
        Ok(())
    }

    /// The queued items, oldest first.
    pub fn as_slice(&self) -> &[T] {
        &self.items
    }

    /// Mutable access to the queued items.
    pub fn as_mut_slice(&mut self) -> &mut [T] {
        &mut self.items
    }

    /// Empties the queue (keeps its storage).
    #[inline]
    pub fn clear(&mut self) {
        self.items.clear();
    }

    /// Removes the first `n` items (those a consumer has taken), keeping the rest in order.
    pub fn consume(&mut self, n: usize) {
        let n = n.min(self.items.len());
        self.items.drain(..n);
    }

    /// Removes and returns the newest item.
    pub fn pop_back(&mut self) -> Option<T> {
        self.items.pop()
    }

    /// Removes and returns item `i`, shifting later items down (order kept).
    pub fn remove(&mut self, i: usize) -> T {
        self.items.remove(i)
    }

    /// Keeps the items for which `keep` is true, in order.
    pub fn retain(&mut self, keep: impl FnMut(&T) -> bool) {
        self.items.retain(keep);
    }

    /// Number of queued items.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// Whether nothing is queued.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Capacity fixed at creation.
    pub fn capacity(&self) -> usize {
        self.cap
    }

    /// Free slots.
    pub fn remaining(&self) -> usize {
        self.cap - self.items.len()
    }

    /// Pushes refused because the queue was full, since creation.
    pub fn overflows(&self) -> u64 {
        self.overflows
    }
}

impl<T: Copy> Bounded<T> {
    /// Appends as many of `items` as fit; returns how many did.
    pub fn extend_from_slice(&mut self, items: &[T]) -> usize {
        let n = items.len().min(self.remaining());
        self.items.extend_from_slice(&items[..n]);
        if n < items.len() {
            self.overflows += 1;
        }
        n
    }

    /// Moves the oldest items into `out`, as many as fit; returns how many.
    pub fn pop_into(&mut self, out: &mut [T]) -> usize {
        let n = out.len().min(self.items.len());
        out[..n].copy_from_slice(&self.items[..n]);
        self.consume(n);
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn never_grows() {
        let mut q = Bounded::with_capacity(3);
        for i in 0..3 {
            q.push(i).unwrap();
        }
        assert_eq!(q.push(9), Err(Full { capacity: 3 }));
        assert_eq!(q.as_slice(), [0, 1, 2]);
        assert_eq!(q.overflows(), 1);
        q.consume(2);
        assert_eq!(q.as_slice(), [2]);
        assert_eq!(q.extend_from_slice(&[5, 6, 7]), 2);
        assert_eq!(q.as_slice(), [2, 5, 6]);
        assert_eq!(q.items.capacity(), 3, "storage was never reallocated");
    }

    #[test]
    fn pop_into_moves_the_oldest_that_fit() {
        let mut q = Bounded::with_capacity(4);
        q.extend_from_slice(&[1, 2, 3]);
        let mut out = [0; 2];
        assert_eq!(q.pop_into(&mut out), 2);
        assert_eq!((out, q.as_slice()), ([1, 2], &[3][..]));
        let mut out = [0; 4];
        assert_eq!(q.pop_into(&mut out), 1);
        assert_eq!(out, [3, 0, 0, 0]);
        assert!(q.is_empty());
    }
}
