//! Small shared helpers for the parallel loops: a pointer that crosses threads for disjoint
//! writes, and the dot product every solver uses (one summation order everywhere).

/// A raw pointer that may cross threads; every use writes a range no other task touches.
pub(crate) struct SyncPtr<T = f64>(*mut T);
impl<T> Clone for SyncPtr<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for SyncPtr<T> {}
unsafe impl<T: Send> Send for SyncPtr<T> {}
unsafe impl<T: Send> Sync for SyncPtr<T> {}
impl<T> SyncPtr<T> {
    pub(crate) fn new(s: &mut [T]) -> Self {
        Self(s.as_mut_ptr())
    }
    /// # Safety
    /// The range must lie inside the slice this pointer came from, and no other live reference
    /// may overlap it.
    #[allow(clippy::mut_from_ref)]
    pub(crate) unsafe fn slice(&self, start: usize, len: usize) -> &mut [T] {
        std::slice::from_raw_parts_mut(self.0.add(start), len)
    }
}

/// Σ aᵢ bᵢ, summed in index order (the order every result of the solver is reproduced with).
#[inline]
pub(crate) fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Runs `f(parts, share)` over consecutive `parts`, halved in parallel until a half weighs at
/// most `serial`. Part p's share of `out` starts at `start(p)`, shares of consecutive parts are
/// contiguous, and `start(parts.end)` ends the last one; `weight(p)` is the work before part p
/// (non-decreasing, like `start`). Each share is written by one task, with no unsafe code.
pub(crate) fn for_parts<T: Send>(
    parts: std::ops::Range<usize>,
    out: &mut [T],
    (start, weight): (
        &(impl Fn(usize) -> usize + Sync),
        &(impl Fn(usize) -> usize + Sync),
    ),
    serial: usize,
    f: &(impl Fn(std::ops::Range<usize>, &mut [T]) + Sync),
) {
    let (first, last) = (weight(parts.start), weight(parts.end));
    if last - first <= serial || parts.len() < 2 {
        return f(parts, out);
    }
    // the first part from which the weight before it reaches half, kept inside the range
    let half = first + (last - first) / 2;
    let (mut lo, mut hi) = (parts.start + 1, parts.end - 1);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        match weight(mid) < half {
            true => lo = mid + 1,
            false => hi = mid,
        }
    }
    let (a, b) = out.split_at_mut(start(lo) - start(parts.start));
    rayon::join(
        || for_parts(parts.start..lo, a, (start, weight), serial, f),
        || for_parts(lo..parts.end, b, (start, weight), serial, f),
    );
}
