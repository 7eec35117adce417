//! Per-axis collections: a set of axes ([`AxisSet`], one bit each) and a value for every axis
//! ([`AxisMap`]), both indexed by [`Axis`] so that no caller ever turns an axis into an array
//! index (and no look-up can miss).

use core::ops::{Index, IndexMut};

use crate::Axis;

/// Axes on one bus (the one-hex-digit address, brief edition §4-1).
pub const AXES: usize = 16;

/// A set of axes, bit n = axis n.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisSet(pub u16);

impl AxisSet {
    /// Every axis.
    pub const ALL: AxisSet = AxisSet(u16::MAX);
    /// No axis.
    pub const EMPTY: AxisSet = AxisSet(0);

    /// Whether `axis` is in the set.
    pub const fn contains(self, axis: Axis) -> bool {
        self.0 & (1 << axis.get()) != 0
    }

    /// The set with `axis` added.
    #[must_use]
    pub const fn with(self, axis: Axis) -> AxisSet {
        AxisSet(self.0 | 1 << axis.get())
    }

    /// The set without `axis`.
    #[must_use]
    pub const fn without(self, axis: Axis) -> AxisSet {
        AxisSet(self.0 & !(1 << axis.get()))
    }

    /// Whether the set is empty.
    pub const fn is_empty(self) -> bool {
        self.0 == 0
    }

    /// How many axes are in the set.
    pub const fn len(self) -> usize {
        self.0.count_ones() as usize
    }

    /// The first `n` axes (0..n).
    pub const fn first(n: u8) -> AxisSet {
        if n >= 16 {
            AxisSet::ALL
        } else {
            AxisSet((1u16 << n) - 1)
        }
    }

    /// The axes, ascending.
    pub fn iter(self) -> impl Iterator<Item = Axis> {
        Members(self.0)
    }
}

/// The axes of a set, lowest first: one bit scan per axis (the schedule iterates sets of axes
/// many times per transaction; testing all 16 bits each time was measurable on the MCU).
struct Members(u16);

impl Iterator for Members {
    type Item = Axis;

    fn next(&mut self) -> Option<Axis> {
        if self.0 == 0 {
            return None;
        }
        let n = self.0.trailing_zeros() as u8;
        self.0 &= self.0 - 1;
        Axis::new(n)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let n = self.0.count_ones() as usize;
        (n, Some(n))
    }
}

/// The axis with the least key, the first of equal ones: `Iterator::min_by_key` as a plain
/// loop. (`min_by_key` folds (key, item) pairs through closures, which the firmware's
/// opt-level "z" leaves out of line, copying every pair with `memcpy`: 8 % of the firmware's
/// CPU time, measured in QEMU.)
pub(crate) fn least<K: Ord>(
    axes: impl Iterator<Item = Axis>,
    mut key: impl FnMut(Axis) -> K,
) -> Option<Axis> {
    let mut best: Option<(K, Axis)> = None;
    for axis in axes {
        let k = key(axis);
        if best.as_ref().is_none_or(|(b, _)| k < *b) {
            best = Some((k, axis));
        }
    }
    best.map(|(_, axis)| axis)
}

impl FromIterator<Axis> for AxisSet {
    fn from_iter<I: IntoIterator<Item = Axis>>(iter: I) -> AxisSet {
        iter.into_iter().fold(AxisSet::EMPTY, AxisSet::with)
    }
}

/// One `T` for every axis, indexed by [`Axis`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisMap<T>([T; AXES]);

impl<T: Copy> AxisMap<T> {
    /// `value` for every axis: the array made by a function of its own (`repeat`, not inlined),
    /// whose result is its return place, so the map is written where the caller wants it.
    // (`AxisMap([value; AXES])` made the array in this frame and copied it out: 1.7 KB of stack
    // at start-up for the engine's per-axis state, `scripts/stack_depth.py`.) Inlined itself: a
    // call of `repeat` is all it is, and out of line it was a 12-byte copy per type (120 B of
    // the F103's flash; the constructors' frames the same, measured).
    #[inline(always)]
    pub const fn new(value: T) -> AxisMap<T> {
        AxisMap(repeat(value))
    }

    /// `value` for every axis, in place (no map-sized temporary).
    pub fn fill(&mut self, value: T) {
        self.0.fill(value);
    }
}

/// `[value; AXES]`, made in the caller's place for it (see [`AxisMap::new`]).
#[inline(never)]
const fn repeat<T: Copy>(value: T) -> [T; AXES] {
    [value; AXES]
}

impl<T> AxisMap<T> {
    /// Every axis with its value, ascending.
    pub fn iter(&self) -> impl Iterator<Item = (Axis, &T)> {
        Axis::all().zip(self.0.iter())
    }

    /// Every axis with its value, mutably.
    pub fn iter_mut(&mut self) -> impl Iterator<Item = (Axis, &mut T)> {
        Axis::all().zip(self.0.iter_mut())
    }

    /// The values, axis 0 first.
    pub fn values(&self) -> impl Iterator<Item = &T> {
        self.0.iter()
    }

    /// The values, mutably.
    pub fn values_mut(&mut self) -> impl Iterator<Item = &mut T> {
        self.0.iter_mut()
    }
}

impl<T: Default + Copy> Default for AxisMap<T> {
    fn default() -> AxisMap<T> {
        AxisMap::new(T::default())
    }
}

// `Axis` holds 0..=15 by construction and the array has 16 entries, so these look-ups cannot
// fail; the mask makes that visible to the compiler too, so no bounds check (and no panic
// path) is emitted.
#[allow(clippy::indexing_slicing)]
impl<T> Index<Axis> for AxisMap<T> {
    type Output = T;
    fn index(&self, axis: Axis) -> &T {
        &self.0[usize::from(axis.get()) & (AXES - 1)]
    }
}

#[allow(clippy::indexing_slicing)]
impl<T> IndexMut<Axis> for AxisMap<T> {
    fn index_mut(&mut self, axis: Axis) -> &mut T {
        &mut self.0[usize::from(axis.get()) & (AXES - 1)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A few thousand sets, from a fixed xorshift sequence (every bit pattern class: empty,
    /// full, single axes, sparse and dense).
    fn sets() -> impl Iterator<Item = AxisSet> {
        let mut x: u32 = 0x9e37_79b9;
        let random = core::iter::from_fn(move || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            Some(AxisSet(x as u16))
        });
        [AxisSet::EMPTY, AxisSet::ALL, AxisSet(1), AxisSet(0x8000)]
            .into_iter()
            .chain(random.take(4000))
    }

    #[test]
    fn iter_gives_the_members_lowest_first() {
        for set in sets() {
            let members = set.iter();
            assert_eq!(members.size_hint(), (set.len(), Some(set.len())));
            let bits = members.fold(AxisSet::EMPTY, |seen, a| {
                assert!(set.contains(a), "{a:?} not in {set:?}");
                assert!(
                    seen.0 >> a.get() == 0,
                    "{a:?} after a higher axis in {set:?}"
                );
                seen.with(a)
            });
            assert_eq!(bits, set);
        }
    }

    #[test]
    fn least_is_min_by_key_first_of_equals() {
        // Keys with many ties (so "the first of equals" is exercised) and without.
        let keys: [fn(Axis) -> u32; 3] = [
            |a| u32::from(a.get() % 3),
            |a| u32::from(15 - a.get()),
            |a| u32::from(a.get()).wrapping_mul(0x9e37_79b9) >> 28,
        ];
        for set in sets() {
            for key in keys {
                assert_eq!(
                    least(set.iter(), key),
                    set.iter().min_by_key(|&a| key(a)),
                    "{set:?}"
                );
            }
        }
    }
}
