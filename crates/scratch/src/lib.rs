//! Arrays of plain values ([`Buffer`]) that hold up to a few megabytes on the heap and, past that,
//! move to an unnamed scratch file mapped into memory ([`ScratchVec`]).
//!
//! A long log's record holds a number per sensor unit and block: a 1 kHz skin of 1000 SUs in
//! 10 ms blocks is 72 MB a minute in single precision, and a fit reads all of it in every
//! iteration. On the heap it is anonymous memory the process must keep for as long as it runs;
//! in a mapped file it is the page cache's, which the kernel writes out and drops when memory
//! runs short and reads back when the fit comes to it again. The file has no name (it is gone
//! when the process ends, however it ends) and lies in the system's temporary directory
//! (`TMPDIR`): on a disk, not on a `tmpfs`, which is memory again.
//!
//! The only `unsafe` code is the mapping itself; see [`ScratchVec`] for why it is sound.

use std::fs::File;
use std::io;
use std::marker::PhantomData;
use std::ops::{Deref, DerefMut};

use bytemuck::Pod;
use memmap2::{MmapMut, MmapOptions};

/// The most a [`Buffer`] holds on the heap by default, bytes (4 MiB).
pub const HEAP_LIMIT: usize = 4 << 20;

/// The least a [`ScratchVec`] maps, bytes: a mapping is never empty.
const MIN_MAPPED: usize = 1 << 16;

/// A growable array of plain values in an unnamed temporary file, mapped into memory.
///
/// Sound because nothing but this value touches the file: it is created without a name (or
/// unlinked at once where the system cannot), opened by this process alone, only ever grown,
/// never truncated, while mapped; and every byte of the mapped length is reserved on the disk
/// before it is mapped (or written, where the file system cannot reserve), so that storing into
/// the mapping never meets a full disk, which would be a signal rather than an error. The one
/// way around it is another process of the same user writing through `/proc/<pid>/fd`, which
/// could as well write the process's memory.
pub struct ScratchVec<T: Pod> {
    file: File,
    map: MmapMut,
    len: usize,
    capacity: usize,
    values: PhantomData<T>,
}

impl<T: Pod> ScratchVec<T> {
    /// An empty array with room for `capacity` values, in a new scratch file.
    pub fn with_capacity(capacity: usize) -> io::Result<Self> {
        let file = tempfile::tempfile()?;
        let capacity = Self::mapped_values(capacity);
        let bytes = Self::bytes(capacity)?;
        reserve(&file, 0, bytes)?;
        let map = Self::map(&file, bytes)?;
        Ok(Self {
            file,
            map,
            len: 0,
            capacity,
            values: PhantomData,
        })
    }

    /// The values held.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether it holds none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// How many values it holds room for without growing the file.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Room for `extra` values more (the file grown by at least half).
    pub fn reserve(&mut self, extra: usize) -> io::Result<()> {
        let needed = self
            .len
            .checked_add(extra)
            .ok_or_else(|| io::Error::other("a scratch array of more values than memory holds"))?;
        if needed <= self.capacity {
            return Ok(());
        }
        let capacity = Self::mapped_values(needed.max(self.capacity + self.capacity / 2));
        let (old, new) = (Self::bytes(self.capacity)?, Self::bytes(capacity)?);
        reserve(&self.file, old, new - old)?;
        self.map = Self::map(&self.file, new)?;
        self.capacity = capacity;
        Ok(())
    }

    /// Appends `values`.
    pub fn extend_from_slice(&mut self, values: &[T]) -> io::Result<()> {
        self.reserve(values.len())?;
        let start = self.len;
        self.len += values.len();
        self[start..].copy_from_slice(values);
        Ok(())
    }

    /// Appends `value`.
    pub fn push(&mut self, value: T) -> io::Result<()> {
        self.extend_from_slice(std::slice::from_ref(&value))
    }

    /// Makes it `len` values long, new ones `value`.
    pub fn resize(&mut self, len: usize, value: T) -> io::Result<()> {
        if len <= self.len {
            self.len = len;
            return Ok(());
        }
        self.reserve(len - self.len)?;
        let start = self.len;
        self.len = len;
        self[start..].fill(value);
        Ok(())
    }

    /// Keeps the first `len` values (the file keeps its size).
    pub fn truncate(&mut self, len: usize) {
        self.len = self.len.min(len);
    }

    /// The same values in a scratch file of their own.
    pub fn try_clone(&self) -> io::Result<Self> {
        let mut copy = Self::with_capacity(self.len)?;
        copy.extend_from_slice(self)?;
        Ok(copy)
    }

    /// `values` rounded up to what a mapping of at least [`MIN_MAPPED`] bytes holds.
    fn mapped_values(values: usize) -> usize {
        let size = std::mem::size_of::<T>().max(1);
        values.max(MIN_MAPPED.div_ceil(size))
    }

    fn bytes(values: usize) -> io::Result<usize> {
        values
            .checked_mul(std::mem::size_of::<T>())
            .ok_or_else(|| io::Error::other("a scratch array of more bytes than memory holds"))
    }

    fn map(file: &File, bytes: usize) -> io::Result<MmapMut> {
        // SAFETY: see the type's documentation: the file is this value's alone, `bytes` of it
        // are reserved, and it is never truncated while mapped.
        unsafe { MmapOptions::new().len(bytes).map_mut(file) }
    }
}

impl<T: Pod> Deref for ScratchVec<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        // The mapping starts on a page, which is aligned for any plain value.
        &bytemuck::cast_slice(&self.map[..])[..self.len]
    }
}

impl<T: Pod> DerefMut for ScratchVec<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        &mut bytemuck::cast_slice_mut(&mut self.map[..])[..self.len]
    }
}

impl<T: Pod> std::fmt::Debug for ScratchVec<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ScratchVec")
            .field("len", &self.len)
            .field("capacity", &self.capacity)
            .finish()
    }
}

/// Reserves `len` bytes of `file` from `offset` on the disk, growing it to their end.
fn reserve(file: &File, offset: usize, len: usize) -> io::Result<()> {
    if len == 0 {
        return Ok(());
    }
    #[cfg(any(target_os = "linux", target_os = "android"))]
    {
        use rustix::fs::{fallocate, FallocateFlags};
        match fallocate(file, FallocateFlags::empty(), offset as u64, len as u64) {
            Ok(()) => return Ok(()),
            Err(e) if e == rustix::io::Errno::OPNOTSUPP => {}
            Err(e) => return Err(e.into()),
        }
    }
    write_zeros(file, offset, len)
}

/// Writes `len` zero bytes at `offset`: the reservation where the file system makes none.
fn write_zeros(file: &File, offset: usize, len: usize) -> io::Result<()> {
    use std::io::{Seek, SeekFrom, Write};
    let zeros = vec![0u8; len.min(1 << 20)];
    let mut file = file;
    file.seek(SeekFrom::Start(offset as u64))?;
    let mut left = len;
    while left > 0 {
        let n = left.min(zeros.len());
        file.write_all(&zeros[..n])?;
        left -= n;
    }
    file.flush()
}

/// A growable array of plain values on the heap until it would hold more than its limit
/// ([`HEAP_LIMIT`] by default), then in a [`ScratchVec`]. Where no scratch file can be made or
/// grown (no temporary directory, a full disk), it stays on (or goes back to) the heap: it never
/// loses a value and never fails.
pub struct Buffer<T: Pod> {
    store: Store<T>,
    limit: usize,
}

enum Store<T: Pod> {
    Heap(Vec<T>),
    Mapped(ScratchVec<T>),
}

impl<T: Pod> Buffer<T> {
    /// An empty buffer that moves to a scratch file past [`HEAP_LIMIT`] bytes.
    pub fn new() -> Self {
        Self::with_limit(HEAP_LIMIT)
    }

    /// An empty buffer that moves to a scratch file past `bytes` bytes.
    pub fn with_limit(bytes: usize) -> Self {
        Self {
            store: Store::Heap(Vec::new()),
            limit: bytes,
        }
    }

    /// `len` copies of `value`.
    pub fn filled(len: usize, value: T) -> Self {
        let mut out = Self::new();
        out.resize(len, value);
        out
    }

    /// Whether its values are in a scratch file.
    pub fn is_mapped(&self) -> bool {
        matches!(self.store, Store::Mapped(_))
    }

    /// Room for `extra` values more, moving to a scratch file if that would take it past its
    /// limit, and back to the heap if the scratch file cannot grow.
    pub fn reserve(&mut self, extra: usize) {
        let limit = self.limit;
        match &mut self.store {
            Store::Heap(v) => {
                let bytes = (v.len().saturating_add(extra)).saturating_mul(size_of::<T>());
                if bytes <= limit {
                    if v.len() + extra > v.capacity() {
                        // A quarter more at a time, not twice as much.
                        v.reserve_exact(extra.max(v.len() / 4).max(256));
                    }
                    return;
                }
                let mapped = ScratchVec::with_capacity(v.len() + extra)
                    .and_then(|mut s| s.extend_from_slice(v).map(|()| s));
                match mapped {
                    Ok(s) => self.store = Store::Mapped(s),
                    Err(_) => {
                        // No scratch: the heap it is, and no second try on every value.
                        self.limit = usize::MAX;
                        v.reserve(extra);
                    }
                }
            }
            Store::Mapped(s) => {
                if s.reserve(extra).is_err() {
                    let mut v = Vec::with_capacity(s.len() + extra);
                    v.extend_from_slice(s);
                    self.store = Store::Heap(v);
                    self.limit = usize::MAX;
                }
            }
        }
    }

    /// Appends `values`.
    pub fn extend_from_slice(&mut self, values: &[T]) {
        self.reserve(values.len());
        match &mut self.store {
            Store::Heap(v) => v.extend_from_slice(values),
            Store::Mapped(s) => s.extend_from_slice(values).expect("the room was reserved"),
        }
    }

    /// Appends `value`.
    pub fn push(&mut self, value: T) {
        self.extend_from_slice(std::slice::from_ref(&value));
    }

    /// Makes it `len` values long, new ones `value`.
    pub fn resize(&mut self, len: usize, value: T) {
        self.reserve(len.saturating_sub(self.len()));
        match &mut self.store {
            Store::Heap(v) => v.resize(len, value),
            Store::Mapped(s) => s.resize(len, value).expect("the room was reserved"),
        }
    }

    /// Keeps the first `len` values.
    pub fn truncate(&mut self, len: usize) {
        match &mut self.store {
            Store::Heap(v) => v.truncate(len),
            Store::Mapped(s) => s.truncate(len),
        }
    }

    /// Removes each value for which `same(value, kept)` holds, `kept` the last value kept before
    /// it (as [`Vec::dedup_by`], with the arguments by value); gives the number removed.
    pub fn dedup_by(&mut self, mut same: impl FnMut(T, T) -> bool) -> usize {
        let len = self.len();
        let mut kept = 0;
        for i in 0..len {
            if kept == 0 || !same(self[i], self[kept - 1]) {
                self[kept] = self[i];
                kept += 1;
            }
        }
        self.truncate(kept);
        len - kept
    }

    /// Gives the heap back what it holds beyond its values (a scratch file keeps its size).
    pub fn shrink_to_fit(&mut self) {
        if let Store::Heap(v) = &mut self.store {
            v.shrink_to_fit();
        }
    }
}

impl<T: Pod> Default for Buffer<T> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Pod> Deref for Buffer<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        match &self.store {
            Store::Heap(v) => v,
            Store::Mapped(s) => s,
        }
    }
}

impl<T: Pod> DerefMut for Buffer<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        match &mut self.store {
            Store::Heap(v) => v,
            Store::Mapped(s) => s,
        }
    }
}

impl<T: Pod> Clone for Buffer<T> {
    /// The same values, in a scratch file of their own where these are in one.
    fn clone(&self) -> Self {
        let mut copy = Self::with_limit(self.limit);
        copy.extend_from_slice(self);
        copy
    }
}

impl<T: Pod> FromIterator<T> for Buffer<T> {
    fn from_iter<I: IntoIterator<Item = T>>(values: I) -> Self {
        let mut out = Self::new();
        for v in values {
            out.push(v);
        }
        out
    }
}

impl<T: Pod> From<Vec<T>> for Buffer<T> {
    fn from(values: Vec<T>) -> Self {
        let mut out = Self::new();
        if values.len() * size_of::<T>() <= out.limit {
            out.store = Store::Heap(values);
        } else {
            out.extend_from_slice(&values);
        }
        out
    }
}

impl<T: Pod + std::fmt::Debug> std::fmt::Debug for Buffer<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Buffer")
            .field("len", &self.len())
            .field("mapped", &self.is_mapped())
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scratch_array_holds_what_was_put_in_across_its_growth() {
        let mut s = ScratchVec::<u64>::with_capacity(0).unwrap();
        assert!(s.is_empty());
        // Past several growths of the mapping (8 KiB of u64 at first).
        for i in 0..100_000u64 {
            s.push(i * 3).unwrap();
        }
        assert_eq!(s.len(), 100_000);
        assert!(s.capacity() >= 100_000);
        assert!(s.iter().enumerate().all(|(i, &v)| v == i as u64 * 3));
        s[7] = 1;
        s.resize(100_010, 9).unwrap();
        assert_eq!(&s[99_999..], &[299_997, 9, 9, 9, 9, 9, 9, 9, 9, 9, 9]);
        s.truncate(8);
        assert_eq!(&s[..], &[0, 3, 6, 9, 12, 15, 18, 1]);
        let copy = s.try_clone().unwrap();
        s[0] = 5;
        assert_eq!(&copy[..], &[0, 3, 6, 9, 12, 15, 18, 1]);
    }

    #[test]
    fn a_buffer_moves_to_a_scratch_file_past_its_limit_and_keeps_every_value() {
        let mut b = Buffer::<[f32; 3]>::with_limit(1200);
        for i in 0..100 {
            b.push([i as f32, 0.5, f32::NAN]);
        }
        assert!(!b.is_mapped(), "1200 bytes fit");
        b.push([100.0, 0.5, f32::NAN]);
        assert!(b.is_mapped(), "1212 bytes do not");
        b.extend_from_slice(&[[101.0, 1.0, 2.0]; 5000]);
        assert_eq!(b.len(), 5101);
        for (i, v) in b.iter().enumerate() {
            let x = if i <= 100 { i as f32 } else { 101.0 };
            assert_eq!(v[0], x);
        }
        assert!(b[100][2].is_nan() && b[5100][2] == 2.0);
        let mut c = b.clone();
        assert!(c.is_mapped());
        c[0][0] = -1.0;
        assert_eq!((b[0][0], c[0][0]), (0.0, -1.0));
        b.resize(3, [0.0; 3]);
        assert_eq!(b.len(), 3);
        let collected: Buffer<f64> = (0..10).map(f64::from).collect();
        assert_eq!(&collected[..], &[0., 1., 2., 3., 4., 5., 6., 7., 8., 9.]);
    }

    #[test]
    fn dedup_keeps_the_first_of_each_run_as_a_vec_does() {
        let values = [1u32, 1, 2, 2, 2, 3, 1, 1, 4];
        let mut expected = values.to_vec();
        expected.dedup();
        for limit in [1024, 8] {
            let mut b = Buffer::with_limit(limit);
            b.extend_from_slice(&values);
            assert_eq!(b.is_mapped(), limit == 8);
            assert_eq!(b.dedup_by(|a, b| a == b), 4);
            assert_eq!(&b[..], &expected[..]);
        }
        let mut empty = Buffer::<u8>::new();
        assert_eq!(empty.dedup_by(|a, b| a == b), 0);
    }
}
