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
