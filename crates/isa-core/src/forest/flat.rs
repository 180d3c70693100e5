//! Inference-time traversal of one tree by many parts: a compact copy of the tree's split nodes
//! ([`FlatTree`], 32 bytes a node, both children in the node, a child that is a leaf encoded as
//! `!leaf_id`) walked by 16 parts at once with AVX2 gathers (node fields, then both probes'
//! depths), a part that reaches a leaf being replaced in its lane by the next part, so every lane
//! stays busy until the last parts. The decisions are those of
//! [`Tree::leaf_of`](crate::tree::Tree::leaf_of) (same f32 arithmetic, same rounding, same
//! background rule); without AVX2 the portable [`leaves_batched`] runs instead. Tests check both paths against each other and against `leaf_of`.

use crate::depth::ImageRef;
use crate::probe::probe;
use crate::tree::Tree;

/// A split node: probe offsets `u = (ux, uy)`, `v = (vx, vy)` (pixel·metres), threshold, and
/// the children for `f < thr` (`left`) and `f >= thr` (`right`): a node index `>= 0`, or
/// `!leaf_id` (< 0) for a leaf.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(32))]
pub(crate) struct FlatNode {
    pub ux: f32,
    pub uy: f32,
    pub vx: f32,
    pub vy: f32,
    pub thr: f32,
    pub left: i32,
    pub right: i32,
    pad: i32,
}

/// A tree prepared for [`FlatTree::leaves`].
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum FlatTree {
    /// The root is a leaf: every part reaches it.
    Leaf(u32),
    /// Split nodes by node id (the entries of leaves are unused).
    Nodes(Vec<FlatNode>),
}

/// A forest's trees prepared for the fast traversal, built on first use and kept with the forest
/// (converting a paper-scale forest takes milliseconds, as long as traversing a whole object).
/// Keyed by each tree's node array (address and length): a forest whose `trees` are replaced or
/// resized is prepared again. Equality, `Debug` and `Clone` ignore it (a clone prepares its own).
#[derive(Default)]
pub(crate) struct FlatCache(std::sync::OnceLock<Prepared>);

/// The node arrays' (address, length) keys, and the prepared trees.
type Prepared = (Vec<(usize, usize)>, Option<Vec<FlatTree>>);

impl FlatCache {
    /// The prepared trees of `trees` (`None`: no AVX2, or a tree unfit for the fast path).
    pub(crate) fn get(
        &self,
        trees: &[crate::tree::Tree],
    ) -> Option<std::borrow::Cow<'_, [FlatTree]>> {
        use rayon::prelude::*;
        use std::borrow::Cow;
        if !FlatTree::available() {
            return None;
        }
        let key: Vec<(usize, usize)> = trees
            .iter()
            .map(|t| (t.nodes.as_ptr() as usize, t.nodes.len()))
            .collect();
        let build = || -> Option<Vec<FlatTree>> { trees.par_iter().map(FlatTree::new).collect() };
        let (k, flat) = self.0.get_or_init(|| (key.clone(), build()));
        if *k == key {
            flat.as_deref().map(Cow::Borrowed)
        } else {
            build().map(Cow::Owned)
        }
    }
}

impl Clone for FlatCache {
    fn clone(&self) -> Self {
        FlatCache::default()
    }
}

impl PartialEq for FlatCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for FlatCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("FlatCache")
    }
}

impl FlatTree {
    /// `None` when the tree is not well formed for the fast path (children must come after
    /// their parent and be in range, as model files and the builder guarantee; ids must fit
    /// 28 bits): the caller then uses the portable traversal, which checks every index.
    pub fn new(tree: &Tree) -> Option<FlatTree> {
        let nodes = &tree.nodes;
        let n = nodes.len();
        if n == 0 || n >= 1 << 28 {
            return None;
        }
        if nodes[0].is_leaf {
            return Some(FlatTree::Leaf(nodes[0].child));
        }
        let enc = |j: usize| -> Option<i32> {
            let nd = nodes.get(j)?;
            if nd.is_leaf {
                (nd.child < 1 << 30).then_some(!(nd.child as i32))
            } else {
                Some(j as i32)
            }
        };
        let mut flat = vec![FlatNode::default(); n];
        for (i, nd) in nodes.iter().enumerate() {
            if nd.is_leaf {
                continue;
            }
            let c = nd.child as usize;
            if c <= i {
                return None;
            }
            flat[i] = FlatNode {
                ux: nd.feature.u[0],
                uy: nd.feature.u[1],
                vx: nd.feature.v[0],
                vy: nd.feature.v[1],
                thr: nd.threshold,
                left: enc(c)?,
                right: enc(c + 1)?,
                pad: 0,
            };
        }
        Some(FlatTree::Nodes(flat))
    }

    /// Whether [`leaves`](Self::leaves) can run (AVX2 available at run time).
    pub fn available() -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            std::arch::is_x86_feature_detected!("avx2")
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            false
        }
    }

    /// Leaf of every part `(u, v, depth mm)` (see the module docs); `out.len() == parts.len()`.
    ///
    /// # Safety
    /// [`available`](Self::available) must be true, and `img.data` must be followed in memory by
    /// at least one readable `u16` (a [`DepthStore`](crate::depth::DepthStore) image is: the
    /// store keeps a padding pixel after its last image), as depths are read by 32-bit gathers.
    pub unsafe fn leaves(&self, img: &ImageRef<'_>, parts: &[(i32, i32, u16)], out: &mut [u32]) {
        assert_eq!(parts.len(), out.len());
        match self {
            FlatTree::Leaf(l) => out.fill(*l),
            FlatTree::Nodes(nodes) => {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: forwarded from the caller; `nodes` came from `FlatTree::new`.
                unsafe {
                    leaves_avx2(nodes, img, parts, out)
                }
                #[cfg(not(target_arch = "x86_64"))]
                {
                    let _ = (nodes, img);
                    unreachable!("FlatTree::leaves without AVX2")
                }
            }
        }
    }
}

/// Parts traversed together: their independent paths overlap in the CPU (memory latency and
/// mispredicted branches of one hide behind the others).
const LANES: usize = 16;

/// Leaf of every part `(u, v, depth mm > 0)` in `tree` (the portable twin of
/// [`FlatTree::leaves`]): the same decisions as
/// [`Tree::leaf_of`](crate::tree::Tree::leaf_of) (the arithmetic of `Feature::eval_at`, with
/// `1000 / depth` once per part; `f < threshold` goes to `child`; a test checks equality),
/// traversed [`LANES`] parts at a time with branch-free child selection.
pub(crate) fn leaves_batched(
    tree: &Tree,
    img: &ImageRef<'_>,
    parts: &[(i32, i32, u16)],
    out: &mut [u32],
) {
    let nodes = &tree.nodes;
    for (group, out_group) in parts.chunks(LANES).zip(out.chunks_mut(LANES)) {
        let mut idx = [0u32; LANES];
        let mut inv = [0.0f32; LANES];
        for (k, &(_, _, d)) in group.iter().enumerate() {
            inv[k] = 1000.0f32 / f32::from(d.max(1));
        }
        loop {
            let mut moved = false;
            for (k, &(u, v, d)) in group.iter().enumerate() {
                let nd = &nodes[idx[k] as usize];
                if nd.is_leaf {
                    continue;
                }
                moved = true;
                let f = if d == 0 {
                    0.0
                } else {
                    probe(img, u, v, nd.feature.u, inv[k]) - probe(img, u, v, nd.feature.v, inv[k])
                };
                idx[k] = nd.child + u32::from(f >= nd.threshold);
            }
            if !moved {
                break;
            }
        }
        for (o, &i) in out_group.iter_mut().zip(&idx) {
            *o = nodes[i as usize].child;
        }
    }
}

/// Lanes: two vectors of 8, walked in the same loop iteration (independent dependency chains,
/// so the gathers of one overlap the arithmetic of the other).
#[cfg(target_arch = "x86_64")]
const VECS: usize = 2;

/// # Safety
/// AVX2; `nodes` from `FlatTree::new` (every child index in range, root a split); a readable
/// `u16` after `img.data`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn leaves_avx2(
    nodes: &[FlatNode],
    img: &ImageRef<'_>,
    parts: &[(i32, i32, u16)],
    out: &mut [u32],
) {
    use std::arch::x86_64::*;
    const L: usize = 8 * VECS;
    let n = parts.len();
    // Lane state, the source of truth between iterations.
    let mut node = [0i32; L];
    let mut px = [0i32; L];
    let mut py = [0i32; L];
    let mut inv = [0.0f32; L];
    let mut part = [0usize; L];
    let mut active: u32 = 0;
    let mut next_part = 0usize;
    let load = |k: usize| -> (i32, i32, f32) {
        let (u, v, d) = parts[k];
        // 1000 / D_mm as `Feature::eval_at`; a part without depth gets inv = 0, so both probes
        // read its own (missing) pixel: f = BACKGROUND - BACKGROUND = 0, as the scalar paths.
        (
            u,
            v,
            if d == 0 {
                0.0
            } else {
                1000.0f32 / f32::from(d)
            },
        )
    };
    for lane in 0..L {
        if next_part < n {
            (px[lane], py[lane], inv[lane]) = load(next_part);
            part[lane] = next_part;
            active |= 1 << lane;
            next_part += 1;
        }
    }
    let fbase = nodes.as_ptr() as *const f32;
    let ibase = nodes.as_ptr() as *const i32;
    let p8 = crate::probe::Probe8::new(img);
    let probe = |x: __m256i, y: __m256i, inv: __m256, ox: __m256, oy: __m256| -> __m256 {
        p8.depth(x, y, inv, ox, oy)
    };
    while active != 0 {
        let mut reached = [0u32; VECS];
        for (v, r) in reached.iter_mut().enumerate() {
            let o = v * 8;
            let nd = _mm256_loadu_si256(node.as_ptr().add(o) as *const __m256i);
            let x = _mm256_loadu_si256(px.as_ptr().add(o) as *const __m256i);
            let y = _mm256_loadu_si256(py.as_ptr().add(o) as *const __m256i);
            let iv = _mm256_loadu_ps(inv.as_ptr().add(o));
            // Field k of node i at f32 index 8 i + k.
            let at = _mm256_slli_epi32::<3>(nd);
            let ux = _mm256_i32gather_ps::<4>(fbase, at);
            let uy = _mm256_i32gather_ps::<4>(fbase.add(1), at);
            let vx = _mm256_i32gather_ps::<4>(fbase.add(2), at);
            let vy = _mm256_i32gather_ps::<4>(fbase.add(3), at);
            let thr = _mm256_i32gather_ps::<4>(fbase.add(4), at);
            let left = _mm256_i32gather_epi32::<4>(ibase.add(5), at);
            let right = _mm256_i32gather_epi32::<4>(ibase.add(6), at);
            let f = _mm256_sub_ps(probe(x, y, iv, ux, uy), probe(x, y, iv, vx, vy));
            let ge = _mm256_cmp_ps::<_CMP_GE_OQ>(f, thr);
            let next = _mm256_castps_si256(_mm256_blendv_ps(
                _mm256_castsi256_ps(left),
                _mm256_castsi256_ps(right),
                ge,
            ));
            _mm256_storeu_si256(node.as_mut_ptr().add(o) as *mut __m256i, next);
            *r = _mm256_movemask_ps(_mm256_castsi256_ps(next)) as u32;
        }
        // Lanes at a leaf: record it (active lanes), then start the next part there, or park
        // the lane at the root (an idle lane keeps walking valid nodes; its leaves are ignored).
        for (v, &r) in reached.iter().enumerate() {
            let mut m = r;
            while m != 0 {
                let lane = v * 8 + m.trailing_zeros() as usize;
                m &= m - 1;
                if active & (1 << lane) != 0 {
                    out[part[lane]] = !node[lane] as u32;
                    if next_part < n {
                        (px[lane], py[lane], inv[lane]) = load(next_part);
                        part[lane] = next_part;
                        next_part += 1;
                    } else {
                        active &= !(1 << lane);
                    }
                }
                node[lane] = 0;
            }
        }
    }
}
