//! How one sheet's rim is laid onto another's: corner onto corner, and in between by each
//! span's length where it bent, or along the line between its corners where it stretched.

use super::rim::{Rim, RimAlignment};
use nalgebra::Vector3;

/// A source corner takes a target corner at most this share of the target's rim from where the
/// alignment puts it.
const CORNER_REACH: f64 = 0.05;

/// How the source's rim is laid onto the target's between corners. Each source corner takes the
/// target corner nearest where the alignment puts it (within [`CORNER_REACH`] of the target's
/// length): a twist stretches a sheet's long edges and not its short ones, so the same share of
/// each whole rim is off by up to a few percent of it near the corners. Between two matched
/// corners a point lands at the same share of the span's length where the span kept its length
/// better than the straight line between its corners did (bending keeps the length and
/// shortens the line), and at the same share along that line where the line kept its length
/// better: a surface pushed across it (a saddle, a sheet pressed into a bowl) stretches most
/// where it is steepest, and a point of the rim keeps its place between the corners as seen
/// from the line through them. That share must grow along both spans; where it does not (a
/// span that both stretched and curled round), the share of the length is taken. With no
/// corner matched, the same share of each whole rim.
#[derive(Clone, Debug, Default)]
pub(crate) struct RimMap {
    /// The source's arc length at each matched corner, ascending.
    arc: Vec<f64>,
    /// The target's arc length less the aligned one there.
    offset: Vec<f64>,
    /// The source rim's length.
    length: f64,
    /// Per matched corner, the span to the next one where it is laid by its chord.
    chords: Vec<Option<ChordSpan>>,
}

/// A span of both rims between two matched corners, laid by the share along each one's chord:
/// for each rim vertex of the span its share along the chord and its distance from the first
/// corner along the rim, both ascending.
#[derive(Clone, Debug)]
struct ChordSpan {
    source: Vec<(f64, f64)>,
    target: Vec<(f64, f64)>,
    /// The target's arc length at the first corner, and the way its arc runs (±1).
    target_start: f64,
    direction: f64,
}

/// A matched pair of corners: their indices in each rim's loop.
struct CornerPair {
    source: usize,
    target: usize,
}

impl RimMap {
    /// The corners of `source` (its rim and the mesh's vertices) matched to those of `target`
    /// under `alignment`, and the spans between them laid by their chords where they stretched.
    pub(crate) fn new(
        source: (&Rim, &[Vector3<f64>]),
        target: (&Rim, &[Vector3<f64>]),
        alignment: &RimAlignment,
    ) -> Self {
        let (s_rim, t_rim) = (source.0, target.0);
        let t_corners = t_rim.corners();
        let mut out = Self {
            length: s_rim.length,
            ..Self::default()
        };
        let mut pairs = Vec::new();
        for i in s_rim.corners() {
            let aligned = aligned_arc(s_rim, t_rim, i, alignment);
            let nearest = t_corners
                .iter()
                .map(|&c| (c, circular_difference(t_rim.arc[c] - aligned, t_rim.length)))
                .min_by(|a, b| a.1.abs().total_cmp(&b.1.abs()));
            if let Some((c, d)) = nearest.filter(|(_, d)| d.abs() <= CORNER_REACH * t_rim.length) {
                out.arc.push(s_rim.arc[i]);
                out.offset.push(d);
                pairs.push(CornerPair {
                    source: i,
                    target: c,
                });
            }
        }
        let n = pairs.len();
        out.chords = (0..n)
            .map(|k| {
                let (a, b) = (&pairs[k], &pairs[(k + 1) % n]);
                ChordSpan::new(source, target, (a, b), alignment.direction)
            })
            .collect();
        out
    }

    /// The arc length of `target`'s rim at which the partner of `source`'s rim vertex `i` lies
    /// under `alignment`.
    pub(crate) fn partner_arc(
        &self,
        source: &Rim,
        target: &Rim,
        i: usize,
        alignment: &RimAlignment,
    ) -> f64 {
        let aligned = aligned_arc(source, target, i, alignment);
        self.target_arc(source.arc[i], aligned)
    }

    /// The target's arc length for the source's arc length `s`, which the alignment alone
    /// puts at `aligned`.
    fn target_arc(&self, s: f64, aligned: f64) -> f64 {
        let n = self.arc.len();
        match n {
            0 => aligned,
            1 => aligned + self.offset[0],
            _ => {
                let k = self.arc.partition_point(|&a| a <= s);
                // the corners before and after s, round the loop
                let (before, after) = ((k + n - 1) % n, k % n);
                let into = (s - self.arc[before]).rem_euclid(self.length);
                if let Some(chord) = &self.chords[before] {
                    return chord.target_arc(into);
                }
                let span = (self.arc[after] - self.arc[before]).rem_euclid(self.length);
                let t = if span > 0.0 { into / span } else { 0.0 };
                aligned + self.offset[before] + t * (self.offset[after] - self.offset[before])
            }
        }
    }
}

impl ChordSpan {
    /// The span from corner pair `a` to `b`, or `None` where it kept its length, or where the
    /// share along a chord does not grow along its span.
    fn new(
        source: (&Rim, &[Vector3<f64>]),
        target: (&Rim, &[Vector3<f64>]),
        (a, b): (&CornerPair, &CornerPair),
        direction: f64,
    ) -> Option<Self> {
        let s_table = chord_table(source.0, source.1, a.source, b.source, 1.0)?;
        let t_table = chord_table(target.0, target.1, a.target, b.target, direction)?;
        let chord = |rim: &Rim, points: &[Vector3<f64>], p: &CornerPair, q: &CornerPair, side| {
            let (i, j) = if side {
                (p.source, q.source)
            } else {
                (p.target, q.target)
            };
            (points[rim.vertices[j] as usize] - points[rim.vertices[i] as usize]).norm()
        };
        let arc_change = (t_table.last()?.1 / s_table.last()?.1 - 1.0).abs();
        let chord_change =
            (chord(target.0, target.1, a, b, false) / chord(source.0, source.1, a, b, true) - 1.0)
                .abs();
        // bent, the span keeps its length and its chord shortens; stretched across the line
        // between its corners, the chord keeps its length
        // (NaN, from a span of no length, is neither)
        if chord_change.partial_cmp(&arc_change) != Some(std::cmp::Ordering::Less) {
            return None;
        }
        Some(Self {
            source: s_table,
            target: t_table,
            target_start: target.0.arc[a.target],
            direction,
        })
    }

    /// The target's arc length for the point `into` along the source's span.
    fn target_arc(&self, into: f64) -> f64 {
        let share = interpolate(&self.source, into, |p| p.1, |p| p.0);
        self.target_start + self.direction * interpolate(&self.target, share, |p| p.0, |p| p.1)
    }
}

/// For the rim vertices from loop index `from` to `to` (inclusive, walking the loop forwards
/// for `direction` +1, backwards for −1): each one's share along the chord between the two and
/// its distance from `from` along the rim. `None` unless the share grows strictly from 0 to 1.
fn chord_table(
    rim: &Rim,
    points: &[Vector3<f64>],
    from: usize,
    to: usize,
    direction: f64,
) -> Option<Vec<(f64, f64)>> {
    let n = rim.vertices.len();
    let at = |k: usize| points[rim.vertices[k] as usize];
    let (start, chord) = (at(from), at(to) - at(from));
    let length = chord.norm_squared();
    if length.is_nan() || length <= 0.0 {
        return None;
    }
    let mut table = vec![(0.0, 0.0)];
    let (mut k, mut walked) = (from, 0.0);
    while k != to {
        let next = if direction > 0.0 {
            (k + 1) % n
        } else {
            (k + n - 1) % n
        };
        walked += (at(next) - at(k)).norm();
        let share = (at(next) - start).dot(&chord) / length;
        if share <= table.last()?.0 {
            return None;
        }
        table.push((share, walked));
        k = next;
    }
    Some(table)
}

/// The linear interpolation through `table` (ascending in `key`) of `value` at `x`, held at the
/// ends.
fn interpolate<T>(table: &[T], x: f64, key: impl Fn(&T) -> f64, value: impl Fn(&T) -> f64) -> f64 {
    let k = table.partition_point(|p| key(p) <= x);
    if k == 0 {
        return table.first().map_or(0.0, &value);
    }
    if k == table.len() {
        return table.last().map_or(0.0, &value);
    }
    let (p, q) = (&table[k - 1], &table[k]);
    let t = (x - key(p)) / (key(q) - key(p));
    value(p) + t * (value(q) - value(p))
}

/// The arc length of `target` at the same share of its length as `source`'s rim vertex `i` of
/// `source`'s, laid on as `alignment` says.
fn aligned_arc(source: &Rim, target: &Rim, i: usize, alignment: &RimAlignment) -> f64 {
    let u = source.arc[i] / source.length;
    (alignment.shift + alignment.direction * u) * target.length
}

/// `d` taken round a loop of `length` into (−length/2, length/2].
fn circular_difference(d: f64, length: f64) -> f64 {
    let d = d.rem_euclid(length);
    if d > 0.5 * length {
        d - length
    } else {
        d
    }
}
