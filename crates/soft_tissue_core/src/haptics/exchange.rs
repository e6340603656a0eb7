//! Lock-free exchange between the haptic thread and the physics: a sequence lock over a few
//! `f64` words. One writer, any number of readers; a reader never blocks the writer and
//! retries only while a write is in progress (a few nanoseconds). Everything is atomics, no
//! `unsafe`, no allocation after construction.

use std::sync::atomic::{AtomicU64, Ordering, fence};

/// `N` `f64` values written together and read together (never a mix of two writes).
#[derive(Debug)]
pub struct SeqCell<const N: usize> {
    seq: AtomicU64,
    data: [AtomicU64; N],
}

impl<const N: usize> SeqCell<N> {
    /// A cell holding `values`.
    pub fn new(values: [f64; N]) -> Self {
        SeqCell {
            seq: AtomicU64::new(0),
            data: values.map(|v| AtomicU64::new(v.to_bits())),
        }
    }

    /// Replaces the values. Only one thread may write a given cell.
    pub fn write(&self, values: [f64; N]) {
        let s = self.seq.load(Ordering::Relaxed);
        self.seq.store(s.wrapping_add(1), Ordering::Relaxed);
        fence(Ordering::Release);
        for (d, v) in self.data.iter().zip(values) {
            d.store(v.to_bits(), Ordering::Relaxed);
        }
        self.seq.store(s.wrapping_add(2), Ordering::Release);
    }

    /// The values of the last completed write, and how many writes there have been.
    pub fn read(&self) -> ([f64; N], u64) {
        loop {
            let s1 = self.seq.load(Ordering::Acquire);
            if s1 & 1 == 1 {
                std::hint::spin_loop();
                continue;
            }
            let values =
                std::array::from_fn(|i| f64::from_bits(self.data[i].load(Ordering::Relaxed)));
            fence(Ordering::Acquire);
            if self.seq.load(Ordering::Relaxed) == s1 {
                return (values, s1 / 2);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use std::sync::atomic::AtomicBool;

    #[test]
    fn readers_never_see_a_torn_write() {
        // The writer always writes four equal values; a torn read would mix two writes.
        let cell = Arc::new(SeqCell::<4>::new([0.0; 4]));
        let stop = Arc::new(AtomicBool::new(false));
        let writer = {
            let (cell, stop) = (cell.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut k = 0.0;
                while !stop.load(Ordering::Relaxed) {
                    k += 1.0;
                    cell.write([k; 4]);
                }
                k
            })
        };
        let mut reads = 0u64;
        let mut last = 0.0;
        while reads < 200_000 {
            let (v, _) = cell.read();
            assert!(v.iter().all(|&x| x == v[0]), "torn read {v:?}");
            assert!(v[0] >= last, "went back in time");
            last = v[0];
            reads += 1;
        }
        stop.store(true, Ordering::Relaxed);
        let written = writer.join().unwrap();
        let (v, count) = cell.read();
        assert_eq!(v, [written; 4]);
        assert_eq!(count as f64, written);
    }
}
