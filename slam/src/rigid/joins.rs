//! The loops that joined map fragments, and the later loops' votes on each join
//! ([`super::loops::KeyframeGraph`]).
//!
//! A loop between two fragments not yet joined places one in the other. In a scene with two
//! places alike, the first loop can come from the look-alike place; every later loop from the
//! same views agrees with it, and the true loops found once the camera reaches a view only the
//! true place has then disagree with the placement. DCS switches off whichever side the solve
//! starts away from, so the map would keep the wrong placement and report its frames as
//! tracked. Each later loop between two fragments of one tree therefore votes on the joins on
//! the path between them: for, when it agrees with the placement within what the odometry's
//! drift and the loops' deviations allow, against otherwise; a loop against votes only if the
//! placement it measures keeps the fragments within their reach (the graph's test for a join:
//! the look-alike place is often out of reach). A join that two loops or more contradict,
//! and at least half as many as support it, is *held apart*: its fragments are placed again
//! without it, and no later loop joins them (NOTES 127). Of two places alike, counting cannot
//! tell which side is true (the look-alike loops come in runs too); held apart, neither
//! side's frames are reported in the other's map.

/// Votes against a join that hold it apart at the least: one loop alone (a look-alike view
/// seen once) never undoes a join, however few loops made it.
const MIN_AGAINST: usize = 2;

/// A loop that joined two trees of map fragments.
#[derive(Clone, Debug)]
pub(super) struct Join {
    /// The joining loop's index among the loops found.
    pub loop_index: usize,
    /// Its keyframes (older, newer) and their fragments.
    pub keyframes: (usize, usize),
    pub fragments: (usize, usize),
    /// Loops that agree with the placement the join made (the joining loop included), and
    /// loops that contradict it.
    support: usize,
    against: usize,
    /// Whether the loops' votes held the join's fragments apart.
    pub apart: bool,
}

/// One step of a path between fragments: the join crossed, the keyframe it leaves from
/// and the keyframe it arrives at.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Hop {
    pub join: usize,
    pub leave: usize,
    pub arrive: usize,
}

/// The joins made so far, in order.
#[derive(Clone, Debug, Default)]
pub(super) struct Joins {
    list: Vec<Join>,
}

impl Joins {
    /// Records that loop `loop_index` between `keyframes` in `fragments` joined their trees.
    pub fn push(
        &mut self,
        loop_index: usize,
        keyframes: (usize, usize),
        fragments: (usize, usize),
    ) {
        self.list.push(Join {
            loop_index,
            keyframes,
            fragments,
            support: 1,
            against: 0,
            apart: false,
        });
    }

    /// The joins not held apart, in the order they were made.
    pub fn live(&self) -> impl Iterator<Item = (usize, &Join)> {
        self.list.iter().enumerate().filter(|(_, j)| !j.apart)
    }

    /// The index among the loops found of join `k`'s loop.
    pub fn loop_of(&self, k: usize) -> usize {
        self.list[k].loop_index
    }

    /// Each of the joins `hops` crossed, with its votes for and against, for the log.
    pub fn tally(&self, hops: &[Hop]) -> Vec<(usize, usize, usize)> {
        let votes = |h: &Hop| (h.join, self.list[h.join].support, self.list[h.join].against);
        hops.iter().map(votes).collect()
    }

    /// How many joins the loops' votes held apart.
    pub fn held_apart(&self) -> usize {
        self.list.iter().filter(|j| j.apart).count()
    }

    /// Marks join `k` held apart (its placement no longer holds once the others are placed
    /// again without an earlier one).
    pub fn hold_apart(&mut self, k: usize) {
        self.list[k].apart = true;
    }

    /// Whether some join held apart has one fragment among `a` and the other among `b`: two
    /// trees that must not be joined again.
    pub fn keeps_apart(&self, a: &[usize], b: &[usize]) -> bool {
        self.list.iter().filter(|j| j.apart).any(|j| {
            let (x, y) = j.fragments;
            (a.contains(&x) && b.contains(&y)) || (a.contains(&y) && b.contains(&x))
        })
    }

    /// The live joins crossed on the way from fragment `start` to fragment `end` (breadth
    /// first over the joins; the live joins form a forest, so the path is the only one); `None`
    /// when no live join connects them.
    pub fn path(&self, start: usize, end: usize) -> Option<Vec<Hop>> {
        // each fragment reached, with the entry it was reached from and the hop that did it
        let mut reached: Vec<(usize, Option<(usize, Hop)>)> = vec![(start, None)];
        let mut k = 0;
        while k < reached.len() {
            let at = reached[k].0;
            if at == end {
                let mut hops = Vec::new();
                let mut entry = k;
                while let Some((parent, hop)) = reached[entry].1 {
                    hops.push(hop);
                    entry = parent;
                }
                hops.reverse();
                return Some(hops);
            }
            for (index, j) in self.live() {
                let (a, b) = j.fragments;
                let (u, v) = j.keyframes;
                let (next, leave, arrive) = match at {
                    _ if at == a => (b, u, v),
                    _ if at == b => (a, v, u),
                    _ => continue,
                };
                if reached.iter().any(|r| r.0 == next) {
                    continue;
                }
                let hop = Hop {
                    join: index,
                    leave,
                    arrive,
                };
                reached.push((next, Some((k, hop))));
            }
            k += 1;
        }
        None
    }

    /// Counts a loop's vote on the joins `hops` crossed: for when it `agrees` with their
    /// placement, against otherwise. The joins that now have at least [`MIN_AGAINST`] votes
    /// against and half as many as for (a third or more of the loops across them disagree),
    /// not yet held apart.
    pub fn vote(&mut self, hops: &[Hop], agrees: bool) -> Vec<usize> {
        let mut contested = Vec::new();
        for h in hops {
            let j = &mut self.list[h.join];
            if agrees {
                j.support += 1;
            } else {
                j.against += 1;
            }
            if !j.apart && j.against >= MIN_AGAINST && 2 * j.against >= j.support {
                contested.push(h.join);
            }
        }
        contested
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fragments 0–1 joined by a loop between keyframes 5 and 25, 1–2 by 30 and 45.
    fn chain() -> Joins {
        let mut j = Joins::default();
        j.push(0, (5, 25), (0, 1));
        j.push(1, (30, 45), (1, 2));
        j
    }

    #[test]
    fn a_path_crosses_the_joins_between_two_fragments() {
        let j = chain();
        let hops = j.path(2, 0).unwrap();
        let expected = [
            Hop {
                join: 1,
                leave: 45,
                arrive: 30,
            },
            Hop {
                join: 0,
                leave: 25,
                arrive: 5,
            },
        ];
        assert_eq!(hops, expected);
        assert_eq!(j.path(1, 1).unwrap(), []);
        assert!(j.path(0, 3).is_none());
    }

    #[test]
    fn a_join_a_third_of_its_loops_contradict_is_contested() {
        let mut j = chain();
        let hops = j.path(0, 2).unwrap();
        // three more loops for, then against: the second against the first join (4 for, 2
        // against) contests both
        for _ in 0..3 {
            assert!(j.vote(&hops, true).is_empty());
        }
        assert!(j.vote(&hops, false).is_empty());
        assert_eq!(j.vote(&hops, false), [0, 1]);
        j.hold_apart(0);
        assert_eq!(j.held_apart(), 1);
        assert!(j.path(0, 1).is_none());
        assert!(j.keeps_apart(&[0], &[1, 2]));
        assert!(!j.keeps_apart(&[1], &[2]));
    }
}
