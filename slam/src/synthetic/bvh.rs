//! A bounding-volume hierarchy over triangles for ray casting: median splits on the longest axis of
//! the centroid bounds, leaves of up to 4 triangles, iterative traversal (Wald, *On fast
//! construction of SAH-based bounding volume hierarchies*, 2007, for the structure; median splits
//! here for simplicity). Ray-triangle tests by Möller & Trumbore (1997).

use nalgebra::{Point3, Vector3};

#[derive(Clone, Copy, Debug)]
struct Aabb {
    min: Vector3<f64>,
    max: Vector3<f64>,
}

impl Aabb {
    fn empty() -> Self {
        Self {
            min: Vector3::repeat(f64::INFINITY),
            max: Vector3::repeat(f64::NEG_INFINITY),
        }
    }
    fn grow(&mut self, p: &Vector3<f64>) {
        self.min = self.min.inf(p);
        self.max = self.max.sup(p);
    }
    /// Entry distance of the ray into the box, if it enters before `t_max`.
    fn hit(&self, o: &Vector3<f64>, inv_d: &Vector3<f64>, t_max: f64) -> Option<f64> {
        let (mut t0, mut t1) = (0.0f64, t_max);
        for a in 0..3 {
            let (mut near, mut far) = (
                (self.min[a] - o[a]) * inv_d[a],
                (self.max[a] - o[a]) * inv_d[a],
            );
            if near > far {
                std::mem::swap(&mut near, &mut far);
            }
            t0 = t0.max(near);
            t1 = t1.min(far);
            if t0 > t1 {
                return None;
            }
        }
        Some(t0)
    }
}

#[derive(Clone, Debug)]
struct Node {
    bounds: Aabb,
    /// Leaf: first triangle and count; inner: left child index (right = left + 1) and count 0.
    start: usize,
    count: usize,
}

/// A ray hit on a triangle: distance along the ray, triangle and barycentric coordinates of
/// vertices 1 and 2.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    /// Distance along the (unit) ray.
    pub t: f64,
    /// Triangle index in the mesh's face list.
    pub triangle: usize,
    /// Barycentric weight of the triangle's second vertex.
    pub u: f64,
    /// Barycentric weight of the triangle's third vertex.
    pub v: f64,
}

/// A BVH over a fixed set of triangles.
#[derive(Clone, Debug)]
pub struct Bvh {
    nodes: Vec<Node>,
    order: Vec<usize>,
    triangles: Vec<[Vector3<f64>; 3]>,
}

impl Bvh {
    /// Builds the hierarchy over `vertices` and `faces`.
    pub fn new(vertices: &[Point3<f64>], faces: &[[u32; 3]]) -> Self {
        let triangles: Vec<[Vector3<f64>; 3]> = faces
            .iter()
            .map(|f| f.map(|i| vertices[i as usize].coords))
            .collect();
        let centroids: Vec<Vector3<f64>> = triangles
            .iter()
            .map(|t| (t[0] + t[1] + t[2]) / 3.0)
            .collect();
        let mut order: Vec<usize> = (0..triangles.len()).collect();
        let mut nodes = vec![Node {
            bounds: Aabb::empty(),
            start: 0,
            count: triangles.len(),
        }];
        let mut stack = vec![0usize];
        while let Some(n) = stack.pop() {
            let (start, count) = (nodes[n].start, nodes[n].count);
            let mut b = Aabb::empty();
            let mut cb = Aabb::empty();
            for &i in &order[start..start + count] {
                for p in &triangles[i] {
                    b.grow(p);
                }
                cb.grow(&centroids[i]);
            }
            nodes[n].bounds = b;
            if count <= 4 {
                continue;
            }
            let ext = cb.max - cb.min;
            let axis = if ext.x >= ext.y && ext.x >= ext.z {
                0
            } else if ext.y >= ext.z {
                1
            } else {
                2
            };
            let mid = count / 2;
            order[start..start + count].select_nth_unstable_by(mid, |a, b| {
                centroids[*a][axis].total_cmp(&centroids[*b][axis])
            });
            let left = nodes.len();
            nodes.push(Node {
                bounds: Aabb::empty(),
                start,
                count: mid,
            });
            nodes.push(Node {
                bounds: Aabb::empty(),
                start: start + mid,
                count: count - mid,
            });
            nodes[n].start = left;
            nodes[n].count = 0;
            stack.push(left);
            stack.push(left + 1);
        }
        Self {
            nodes,
            order,
            triangles,
        }
    }

    /// The nearest hit of the ray `origin + t dir` (t in (ε, t_max)), if any.
    pub(crate) fn intersect(
        &self,
        origin: &Vector3<f64>,
        dir: &Vector3<f64>,
        t_max: f64,
    ) -> Option<TriangleHit> {
        if self.triangles.is_empty() {
            return None;
        }
        let inv_d = dir.map(|d| 1.0 / d);
        let mut best: Option<TriangleHit> = None;
        let mut limit = t_max;
        let mut stack = [0usize; 64];
        let mut sp = 1;
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp]];
            if node.bounds.hit(origin, &inv_d, limit).is_none() {
                continue;
            }
            if node.count > 0 {
                for &i in &self.order[node.start..node.start + node.count] {
                    if let Some((t, u, v)) = moller_trumbore(origin, dir, &self.triangles[i]) {
                        if t < limit {
                            limit = t;
                            best = Some(TriangleHit {
                                t,
                                triangle: i,
                                u,
                                v,
                            });
                        }
                    }
                }
            } else if sp + 2 <= stack.len() {
                stack[sp] = node.start;
                stack[sp + 1] = node.start + 1;
                sp += 2;
            }
        }
        best
    }
}

/// Möller–Trumbore ray-triangle intersection: (t, u, v) with the hit at (1−u−v) a + u b + v c.
fn moller_trumbore(
    o: &Vector3<f64>,
    d: &Vector3<f64>,
    tri: &[Vector3<f64>; 3],
) -> Option<(f64, f64, f64)> {
    let (e1, e2) = (tri[1] - tri[0], tri[2] - tri[0]);
    let p = d.cross(&e2);
    let det = e1.dot(&p);
    if det.abs() < 1e-14 {
        return None;
    }
    let inv = 1.0 / det;
    let s = o - tri[0];
    let u = s.dot(&p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(&e1);
    let v = d.dot(&q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    let t = e2.dot(&q) * inv;
    (t > 1e-9).then_some((t, u, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bvh_matches_brute_force() {
        // a 20x20 grid of triangles, bent into a bowl
        let n = 20;
        let mut v = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f64 / n as f64 - 0.5, j as f64 / n as f64 - 0.5);
                v.push(Point3::new(x, y, x * x + y * y));
            }
        }
        let mut f = Vec::new();
        for j in 0..n as u32 {
            for i in 0..n as u32 {
                let a = j * (n as u32 + 1) + i;
                f.push([a, a + 1, a + n as u32 + 2]);
                f.push([a, a + n as u32 + 2, a + n as u32 + 1]);
            }
        }
        let bvh = Bvh::new(&v, &f);
        for k in 0..200 {
            let o = Vector3::new(
                (k as f64 * 0.37).sin() * 0.4,
                (k as f64 * 0.91).cos() * 0.4,
                2.0,
            );
            let d = Vector3::new((k as f64 * 0.13).sin() * 0.2, 0.05, -1.0).normalize();
            let brute = bvh
                .triangles
                .iter()
                .enumerate()
                .filter_map(|(i, t)| moller_trumbore(&o, &d, t).map(|h| (h.0, i)))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            let fast = bvh.intersect(&o, &d, f64::INFINITY);
            assert_eq!(brute.map(|b| b.1), fast.map(|h| h.triangle), "ray {k}");
        }
    }
}
