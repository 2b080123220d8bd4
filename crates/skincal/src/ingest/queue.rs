//! A first-in first-out queue stored in blocks of fixed size: it grows a block at a time, with no
//! copy of what it holds and no doubling of its memory, and reuses the blocks it has emptied. The
//! single pass holds millions of skin samples in one; a growing `VecDeque` touched twice their
//! memory and copied them at every doubling.

use std::collections::VecDeque;

/// Items per block.
const BLOCK: usize = 1 << 16;

/// Items in the order they were pushed.
#[derive(Debug)]
pub(super) struct Queue<T> {
    /// The blocks in use, oldest first; only the last is partly filled.
    blocks: VecDeque<Vec<T>>,
    /// Items of the first block already taken.
    head: usize,
    /// Emptied blocks, kept to be filled again.
    spare: Vec<Vec<T>>,
    len: usize,
}

impl<T: Copy> Default for Queue<T> {
    fn default() -> Self {
        Queue {
            blocks: VecDeque::new(),
            head: 0,
            spare: Vec::new(),
            len: 0,
        }
    }
}

impl<T: Copy> Queue<T> {
    pub(super) fn len(&self) -> usize {
        self.len
    }

    pub(super) fn push_back(&mut self, item: T) {
        match self.blocks.back_mut() {
            Some(block) if block.len() < BLOCK => block.push(item),
            _ => {
                let mut block = self
                    .spare
                    .pop()
                    .unwrap_or_else(|| Vec::with_capacity(BLOCK));
                block.push(item);
                self.blocks.push_back(block);
            }
        }
        self.len += 1;
    }

    /// The oldest item.
    pub(super) fn front(&self) -> Option<T> {
        self.blocks.front().and_then(|b| b.get(self.head)).copied()
    }

    /// Takes the oldest item.
    pub(super) fn pop_front(&mut self) -> Option<T> {
        let item = self.front()?;
        self.head += 1;
        self.len -= 1;
        let first = self.blocks.front().map_or(0, Vec::len);
        // A block is done once every item it can take has been taken (or the queue is empty).
        if self.head == first && (first == BLOCK || self.len == 0) {
            if let Some(mut block) = self.blocks.pop_front() {
                block.clear();
                self.spare.push(block);
            }
            self.head = 0;
        }
        Some(item)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig {
            cases: 64,
            rng_seed: proptest::test_runner::RngSeed::Fixed(14),
            ..ProptestConfig::default()
        })]

        /// Any run of pushes and pops gives what a `VecDeque` gives, across many blocks.
        #[test]
        fn behaves_as_a_vecdeque(runs in prop::collection::vec((0usize..3 * BLOCK, 0usize..3 * BLOCK), 1..8)) {
            let mut queue = Queue::default();
            let mut oracle = VecDeque::new();
            let mut next = 0u64;
            for (pushes, pops) in runs {
                for _ in 0..pushes {
                    queue.push_back(next);
                    oracle.push_back(next);
                    next += 1;
                }
                for _ in 0..pops {
                    prop_assert_eq!(queue.pop_front(), oracle.pop_front());
                }
                prop_assert_eq!(queue.len(), oracle.len());
                prop_assert_eq!(queue.front(), oracle.front().copied());
            }
            // Blocks in use never exceed what the items need, plus one.
            prop_assert!(queue.blocks.len() <= queue.len().div_ceil(BLOCK) + 1);
        }
    }
}
