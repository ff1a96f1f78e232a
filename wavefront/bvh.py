"""One bounding volume hierarchy over all primitives of all kinds, traversed breadth-first for whole batches.

Depth-first traversal with a stack per ray does not vectorise.  Instead the
unit of work is a (ray, node) *pair*: every pair whose box the ray enters
before its best hit so far survives, interior nodes expand to two child
pairs, and leaves expand to (ray, primitive) pairs.  Those pass a
conservative float32 test first (a slab test against the primitive's own
padded box, then for triangles whether the ray crosses the triangle's plane
within that box; for trees of spheres only, against its bounding sphere), and
the few that survive it are tested with exactly the arithmetic of the
brute-force intersector (each kind's ``exact_t``), so both find the same
primitive at the same ``t`` for every ray, bit for bit.  Where rays reach
many leaves, each ray's nearest leaves are tested first, in rounds, and
leaves entered beyond the best hit so far are dropped; in big trees the
same is done a few levels higher for whole subtrees (``SUBTREE_LEVELS``), so
a ray that hits nearby does not walk every box along its line down to the
leaves.  No hit lies at t <= T_MIN, so boxes a ray leaves before T_MIN are
dropped too (rays leaving a surface start inside their neighbours' boxes).
Each level is a handful of NumPy calls over all pairs of that level (big
trees take two full levels at a step, testing a node's four grandchildren);
the Python loop runs over the tree's depth (and a few leaf rounds), never
over rays.

The tree is built top-down by median split along the widest axis of the
primitives' box centres, with at most ``LEAF_SIZE`` primitives per leaf
(``BIG_LEAF_SIZE`` in trees of more than ``BIG_TREE`` primitives,
``SPHERE_LEAF_SIZE`` in small trees of spheres only), one
level at a time: each level is a few NumPy calls (a segmented reduction for
the boxes, one sort keyed by (node, centre along the node's axis)) over all
primitives still in interior nodes, so a million triangles build in seconds.
Outsized primitives (by bounding radius: a ground sphere of radius 1000 among
balls of 0.2, W2's three balls of radius 1, a Cornell box's walls) are kept out of the tree and tested by brute force first: inside
the tree their boxes would stretch every node above them, and testing them
first gives many rays a nearby hit that prunes every box beyond it.

Traversal runs in float32 whatever the scene's precision: it only has to be
conservative, never exact, because the primitives of every leaf it reaches are
tested in the scene's precision.  Each ray is first clipped to the root box
in the scene's precision and its origin moved to where it enters, so the
float32 coordinates are never larger than the tree's own; boxes are padded by
far more than the rounding of those coordinates and of the slab arithmetic
(:data:`BOX_PAD`), so a box the exact ray enters is always entered.  float32
halves the bytes every level gathers and doubles the SIMD width, which is
most of what a level costs.

The pads grow with the farthest ray origin (ROUNDING_PAD: the exact test's own
rounding is a few epsilons of ``|o - c|``), and a scene's extent is set by its
farthest reach: the cover's ground sphere puts it at 2,000 units, while all but a
few rays in a million start within 40 of the origin.  Trees of up to
NEAR_TABLES_NODES nodes whose pad for rays from within NEAR_EXTENT of the origin
is smaller than the whole extent's keep two sets of tables: their own at that
near pad, walked by the rays whose origin lies within NEAR_EXTENT / 2 on every
axis (so within NEAR_EXTENT of the origin: every bound here holds with
NEAR_EXTENT as the farthest origin), and ``far``, a copy of the tree at the
whole extent's pad, walking the other rays after them in the same call, each
with the same best hit to beat.  Which tables a ray walks changes only which pairs reach the exact test,
never its answer.

Float32 scenes with huge spheres (the cover scene's ground of radius 1000)
test those reaching past ``FLOAT32_EXTENT`` with the anchored roots
(``geometry.anchored_roots``: the near root as the power of the origin over
the far root, and a relative ``t_min`` for rays from beyond
``FLOAT32_EXTENT``), the others (the cover's balls) with Haines' keyed roots
as in any float32 set (``SphereSet.anchor``).  The hits are still brute force's, exactly:

* the same arithmetic on the same numbers: the leaves' ``t_pairs`` run each
  sphere's own test elementwise on the set's own float32 fields, and each ray's
  ``t_min`` depends on its own origin only (one within FLOAT32_EXTENT gets
  float32 ``T_MIN`` whatever shares its call); the outsized spheres (the
  ground, the balls) are a subset of the same set, copied, tested by brute
  force itself; ties go to the lower index in both;
* no culled pair holds a hit.  Culling uses ``T_MIN``, at most any ray's
  ``t_min``.  The anchored near root errs by ``dP / |big|``, ``dP`` a few
  epsilons of ``|o - q| |o - q'|`` (and of the anchors' own rounding, ``|q|``);
  near a root, moving along the ray by ``dt`` moves the point off the sphere
  by ``|t - h| dt / r`` (``|t - h| = sqrt_disc <= |big|``) plus ``dt^2 / 2r``:
  a few epsilons of ``|o - c| + r + |q|``, as with Haines' roots, which the
  pads cover (ROUNDING_PAD epsilons of the extent), as long as ``|big|`` is not
  tiny.  ``|big| >= sqrt(|P|)`` (the larger of two real roots whose product
  is P), and ``|P| >= e^2`` for an origin ``e`` off the sphere, so ``|big| >=
  e``: it is tiny only for rays starting within ``e`` of the surface (near a
  tangent the quotient ``P / big`` can then land anywhere along the ray,
  measured up to 273 units from a ball of radius 0.2, which is why
  ``anchored_roots`` caps the near root at ``|big|``).  An anchored set's pad is at least
  ROUNDING_PAD float32 epsilons of ``2 FLOAT32_EXTENT`` (3.9e-3, see
  ``BVH._pad``): a ray starting within ``pad - T_MIN`` of a
  sphere starts inside its padded boxes and padded bounding sphere by more
  than ``T_MIN``, so every box and the sphere pass keep that pair whatever its
  root (entry <= 0, leave and far root past the floor) and the exact test
  decides, as in brute force; rays from farther have ``|big| >= 2.9e-3`` and
  the bounds above.  Huge spheres in the leaves (more than MAX_OUTSIZED of
  them) are held by the same bounds; the sphere pass's own float32 rounding
  of ``reach^2 - |l|^2`` stays far below the ``8 r pad`` by which the padded
  sphere's exceeds the sphere's.
(tests/test_bvh.py's anchored tests, with a shrunk pad, a leaf pad of 0,
Haines' roots in the leaves or no relative ``t_min`` there as controls.)

Small trees are stored once per ray octant (signs of the direction's
components), with each child box's planes ordered nearest-first for that
octant, so the slab test needs no min/max of its two planes per axis, and a
pair's node index carries its octant with it; an axis on which every node has
the root's planes (a carpet of equal balls on a floor) is left out of their
walk, its slab folded into each ray's bound once.  Big trees (node-major) store
one table, a node's boxes in one row: gathered rows are copied to pair-minor
columns so that the arithmetic runs on contiguous rows, where a min/max per
axis costs less than eight times the tables' cache footprint.  Their top
(:data:`TOP_NODES`), which stays in cache, is also stored one row per plane,
and its levels gather columns directly, without that copy.
"""

from __future__ import annotations

import copy

import numpy as np

from .geometry import FLOAT32_EXTENT, T_MIN, escaped_at_inf
from .shapes import Hits, Primitives
from .vecmath import gather

LEAF_SIZE = 4
# Trees over more primitives than BIG_TREE get leaves of BIG_LEAF_SIZE, one
# level fewer and half the nodes: on the 1M-triangle terrain 8 was 10 % faster
# than 4 (16 no faster than 8); on W2's 486 spheres 4 was faster than 8 (and 2 is
# faster still since small trees step two levels: SPHERE_LEAF_SIZE).
BIG_LEAF_SIZE = 8
BIG_TREE = 1 << 16
# Spheres-only trees of at most SPHERE_TREE primitives get leaves of SPHERE_LEAF_SIZE: with
# two-level steps (SMALL_STEP_LEVELS) the extra level costs less than the bounding-sphere
# pass of the extra slots (W2's 482 tree spheres: intersection ~3 % faster at 2 than at 4,
# 5 interleaved renders; 3 was ~9 % slower: an incomplete tree).  Capped so that the tree
# stays far below NODE_MAJOR_NODES (twice the nodes of LEAF_SIZE's).
SPHERE_LEAF_SIZE = 2
SPHERE_TREE = 1 << 12
# Rounds of nearest-leaf-first testing before the remaining leaves are tested
# together (see _traverse's test_leaves).
LEAF_ROUNDS = 6
# ... in node-major trees, whose subtree rounds already order the leaves: on the 1M terrain
# 3 leaf rounds were ~2 % faster on bounce rays than 6 (1 was 3 % slower), camera rays level.
BIG_LEAF_ROUNDS = 3
# The float32 bounding-sphere pass of spheres-only leaves grows each radius by
# this many box pads: its own rounding (a few float32 epsilons of the extent)
# is below one.
LEAF_PAD = 4
# Rounds cost a few NumPy calls each, which pays only when rays reach many
# leaves: W2's ~1.5 leaves per ray ran 7 % slower with rounds, the 1M terrain's
# ~10 ran 40 % faster (its exact tests per ray fell from 12 to 5).
LEAF_ROUNDS_ABOVE = 2
# Rays traversed together: the (ray, node) pairs of one level and their
# temporaries then stay in L2, which measured ~2.5x faster per pair than at
# 65,536 rays (about 8 % on W2 end to end; see benchmarks/bench.py).  4096
# against 8192, interleaved in one process on the shared 2-core machine:
# intersection 13-15 % faster on W2, the 1k- and the 1M-triangle terrain
# (2048 was within noise of 4096); but whole W2 renders in one process were
# ~3 % faster at 8192, so small trees kept it.  Session 10, with the renderer's allocator
# settings (render.tune_allocator) and a call cut into batches of equal size (a call of
# 8,193 rays made a batch of 1): 16384 is faster again, each batch's ~250 NumPy calls
# (~1-2 us each whatever their size) shared by twice the rays.  W2's cover scene, its
# recorded intersect calls of a 600x338 render (up to 65,536 rays a call) replayed in one
# process, main's tree and this one alternating, 15 reps: 225 against 236 ns a ray, faster
# in all 15 (12288: 234 against 245; 32768 without equal batches: 4 % slower); renders on
# one worker (abcpu.sh, CPU medians): 600x338 16 spp 3.18 against 3.32 s, W2 (400x225 10
# spp) 0.97 against 1.01.  The outsized brute force kept at 8,192 rays a call inside a
# batch: no faster (-4.2 against -4.4 %).  Session 12, with the near tables' tighter pads (fewer
# pairs a ray) and the floor row: 32768 renders faster again (ab.py, 9 interleaved fresh runs on
# one worker, CPU: the cover at 600x338x16 median ratio 0.957, every run faster, 0.919-0.992;
# W2's 400x225x10 0.966, 0.914-1.026), each batch's ~250 NumPy calls again shared by twice the
# rays; 65536 against 32768: 0.998 (0.967-1.089), within noise.
TRAVERSAL_BATCH = 32768
# Node-major trees: at 4096 the 1M-triangle terrain rendered ~10 % faster than at 8192 while
# every slab test wrote eight fresh arrays; with the reductions in place and the transposed
# copies folded into the subtraction (session 6), 8192 is ~4 % faster than 4096 (intersection
# in the render, 3 interleaved runs each: ~1575 against ~1660 ns a segment; 12288 and 16384
# slower again): half the NumPy calls per ray, and a level's pairs still fit in cache.
TRAVERSAL_BATCH_BIG = 8192
# What one batch's walk may hold at once, whatever the geometry.  A ray's
# (ray, node) pairs grow with the boxes it enters: a ray at the hub of a fan
# of triangles (an OBJ polygon of 200,000 sides) enters every box, and 64
# such rays held 2.5 GB.  A level of more than WALK_PAIRS pairs is walked in
# parts of WALK_PART, one after the other (depth first over the parts, so
# what waits is a few parts a level: tens of MB); leaves are tested at most
# LEAF_SLOTS (ray, primitive) slots at a time (up to ~250 bytes each, in the exact
# test of a slot the box test kept).  A batch of
# ordinary rays stays far below both (the 1M terrain: ~50 pairs a ray).
# Parts share the rays' best hits, so the result is the same hit, exactly.
WALK_PAIRS = 1 << 17
WALK_PART = 1 << 15
LEAF_SLOTS = 1 << 17
# Boxes grow on every side by the larger of two margins.  BOX_PAD of the
# tree's extent covers float32 traversal: rounding of a shifted origin and of
# (plane - origin) * (1 / d) moves a computed slab entry by at most ~2**-21 of
# it.  ROUNDING_PAD machine epsilons of the farthest ray origin cover the
# rounding of the leaf test itself, which finds a hit wherever a ray passes
# within a few epsilons of |oc| of a sphere; a box must never cull such a hit,
# or the two intersectors would disagree.  Both are invisible to culling
# (1e-5 of a 12-unit scene).
BOX_PAD = 2.0 ** -20
ROUNDING_PAD = 64
# Spheres with a radius above OUTSIZED times the median (at most MAX_OUTSIZED
# of them, largest first) are tested outside the tree.  Such a sphere has 16x
# the surface of a typical one, so it is hit often and testing every ray
# against it first is cheap and yields early bounds; inside the tree it would
# stretch all its ancestors' boxes (W2's three balls of radius 1 made the boxes
# over its carpet of 0.2-radius balls five times taller).  4x measured ~20 %
# faster W2 intersection than 8x, and no slower on scenes without such spheres.
OUTSIZED = 4.0
MAX_OUTSIZED = 16
# ... and above OUTSIZED_SHARE of the diagonal of the other primitives' box: a smaller one
# stretches only boxes many levels down, and testing every ray against it costs more than
# that.  W2's balls of radius 1 are 1/31 of its carpet's diagonal; the 1M terrain's two
# largest triangles (4.4x the median radius, 1/170 of the terrain) took 3 % of its
# intersection time tested outside the tree.
OUTSIZED_SHARE = 1 / 64
# Above this many nodes the traversal tables are stored node-major (a node's
# 12 box planes, or a leaf's bounding spheres, in one cache line) instead of
# one row per plane: in a big tree the rows lie megabytes apart and a gathered
# column cost one cache miss per row.  Measured on a 1M-triangle terrain: the
# gathers were two thirds of the traversal.  Small trees (W2: ~250 nodes) fit
# in cache, where the row layout's contiguous arithmetic is faster.
NODE_MAJOR_NODES = 1 << 14
CACHE_LINE = 64  # bytes (x86-64, ARMv8 cores alike); see line_aligned
# ... but the top of a node-major tree, its first TOP_NODES nodes (all levels above depth 13),
# is small enough to stay in cache whatever the tree: there its boxes are also stored one row
# per plane, and a level's columns are gathered directly (in cache, a gathered column costs no
# miss), without the transposed copy of gathered rows, which cost ~5x as much per box.
TOP_NODES = (1 << 14) - 1
# Node-major trees walk their subtrees of SUBTREE_LEVELS levels above the first leaves
# each ray's nearest first, in SUBTREE_ROUNDS rounds (the last takes all that are left).
# On the 1M-triangle terrain, intersection of bounce rays fell from ~4.4 to ~3.45 us per
# ray while camera rays rose from ~1.7 to ~1.9 us (levels 7, rounds 3; a path segment
# ~10 % faster).  Re-measured with the plane pass and two-level steps: levels 4, rounds
# 3 (levels 2 to 7, rounds 2 to 5 tried; within a few per cent of each other).
SUBTREE_LEVELS = 4
SUBTREE_ROUNDS = 3
# Node-major trees step STEP_LEVELS full levels at a time (see _build_traversal_tables'
# descendant_boxes): on the 1M terrain 2 levels were ~7 % faster than 1, 3 no faster
# than 2, 4 ~25 % slower (16 boxes a pair, of which ~2 survive).
STEP_LEVELS = 2
# ... and small trees (octant tables, see _build_traversal_tables' octant_descendants).
SMALL_STEP_LEVELS = 2
# "The 1M terrain" in these notes, through session 7, is the rough terrain (per-vertex noise:
# scenes/make_mesh_models.py terrain(rough=True), the benchmarks' "rough" rows), whose spikes
# are smaller than a pixel at 1M triangles; from session 8 the benchmarks' floor pair is one
# smooth surface cut into 1k and 1M triangles (~0.93 against ~0.53 us a segment, where the rough
# 1M takes ~1.73).  Tuning done on the rough terrain is its worst case, kept as a stress row.
# Tried on the 1M terrain and not kept (session 5; CPU per path segment, A/B interleaved
# against the code as it is, ~2050-2200 ns on a loaded machine):
# - the node-major row tables (leaf slot boxes, descendant boxes) and the top's columns on a
#   16-bit grid over the root box: half the bytes gathered, the same time (2042 against 2041
#   ns, 2091 against 2087 with the top too): the gathers are not bound by bytes;
# - eight octant copies of the top with planes ordered per octant (no min/max): the min/max
#   fell from ~130 to ~25 ns a segment, but gathering from the 8x table rose from ~420 to ~600;
# - nested subtree rounds (another level of rounds 4, 6 or 8 levels above SUBTREE_LEVELS):
#   ~2420 against 2090;
# - one box per pair of slots (leaves ordered by median splits down to pairs, the plane pass
#   over the pair's box): half the boxes, but more plane and exact tests: 2320 against 2217;
# - BIG_LEAF_SIZE 4 or 16, TRAVERSAL_BATCH_BIG 2048 to 8192, TOP_NODES 0 to 32767,
#   STEP_LEVELS 3, SUBTREE_LEVELS 3 or 5, SUBTREE_ROUNDS 4, BIG_LEAF_ROUNDS 2: within noise
#   (a few per cent) or slower.
# ... and in session 6 (intersection of a 1M-terrain render's own recorded rays, CPU per
# ray, ~1550-1700 ns; or in the render itself):
# - transparent huge pages: nothing to do, the tables already sit on them (NumPy madvises
#   arrays of 4 MiB and more; 86-100 % of each big table's pages were huge pages);
# - a treelet-contiguous node layout: breadth-first numbering of a full tree already keeps
#   a node's descendants at each level side by side (a depth-13 node's four grandchildren's
#   rows are adjacent, and their sixteen leaves' rows);
# - reordering each call's rays by a Morton code of their origins (with or without their
#   octant first): 1697-1811 against 1637-1688 with the sort.  The rays of a batch share
#   few leaves whatever their order (3464 (ray, leaf) pairs over 2823 distinct leaves per
#   4096 rays): the terrain's triangles are smaller than a pixel's footprint;
# - one 384-byte record per leaf (slot boxes, planes and primitives): the plane and
#   primitive gathers fell from ~43 to ~22 ms, the bigger rows' gather and transposition
#   rose by ~55 ms (~1835 against ~1700);
# - the top's boxes as rows gathered by gather_minus instead of columns: slower in cache
#   (13-28 against 11-12 ns a pair); 16-byte (complex128) units for the transposed copies:
#   no gain once the copy is folded into the subtraction; two-dimensional nonzero instead
#   of the flat one and a division: 2.5-5 times slower;
# - at TRAVERSAL_BATCH_BIG 8192, BIG_LEAF_ROUNDS 2, SUBTREE_ROUNDS 2, SUBTREE_LEVELS 3 or
#   5, STEP_LEVELS 3, TOP_NODES 32767: within noise (BIG_LEAF_ROUNDS 2, 4 runs each:
#   1619-1655 against 1607-1653; TOP_NODES 32767, 8 runs each: median 1620 against 1620)
#   or slower (STEP_LEVELS 3 and SUBTREE_ROUNDS 2 by ~7 %);
# - the triangles' exact-test rows padded to 16 fields and cache-aligned (two whole lines
#   instead of two or three; cold gathers ~10 % faster in isolation): in the render,
#   intersection 1604/1535/1556/1514 against 1582/1527/1642/1520 ns a segment.  The exact
#   tests' gather of those rows (~73 ns a row in the render, ~28 in isolation) is the
#   largest single cold-miss cost left (~1.9 a segment).
# - (session 6, second round) a float32 edge pass after the plane pass: the exact test's
#   three edge functions (det b1, det b2, det (1 - b1 - b2)) from a per-triangle float32
#   table in the tree's order (a leaf's triangles side by side), a slot dropped only where
#   one is above a margin and another below minus it (conservative: the exact test accepts
#   only where all three share det's sign).  It worked as meant: on the recorded 1M-render
#   rays exact tests fell from 1.79 to 1.20 a ray, hits identical (property tests green),
#   but the pass cost more than the ~0.6 saved cold row gathers: with explicit cross
#   products (~40 NumPy calls, 64-byte rows) 1M 1971/1925 against 1768/1880 ns a segment;
#   in Plucker form (side = a . (o x d) + d . (p x a), 80-byte rows prescaled by the
#   margin, ~15 calls) 1940/1940/1963 against 1788/1868/1852 (np.einsum for it was worse
#   still: ~27 ns a slot).  The pass runs in each leaf round's call on ~1-2 k slots, so
#   its per-call overhead and its own cold gather (one row per kept slot) outweigh the
#   exact tests it saves.
# ... and in session 7 (the recorded rays of a 1M render, ~1430-1640 ns a ray by machine load;
# "in one process": both trees built from the same primitives, runs interleaved):
# - gathering the exact tests' rows in sorted primitive order (monotone addresses): in
#   isolation 3000 random 120-byte rows of 1M cost 53 ns a row, sorted 50, but the argsort
#   and un-permuting the results made it 115;
# - the exact rows in leaf order (a leaf's triangles side by side): the lines those gathers
#   touch fell only from 3.66 to 3.37 a ray (a ray's exact tests rarely share a leaf), for a
#   second 126 MB copy of the rows;
# - leaf rows of one cache line: the slot boxes as uint8 on a grid over the leaf's box
#   (corner and step in float32, 64 bytes instead of 192): the gather fell from 66 to 37 ms,
#   but the uint8 -> float32 transposed copy (50 ms) and the extra multiply-add cost as much
#   (the leaf pass 129 against 138 ms), as the 16-bit grid did in session 5;
# - a slab per leaf (its triangles' mean normal, their extent along it) before the slot
#   boxes: it would drop 0.35 of the 3.76 leaf pairs a ray (the terrain is rougher than a
#   leaf is wide: median slab 0.009 thick); the plane pass over the leaf's span instead of
#   each slot's box, before the boxes: it keeps 8.8 of 28.8 slots a ray, the boxes 5.4;
# - more leaf rounds: 0.95 of the 3.76 leaf pairs a ray lie beyond the ray's final hit
#   (tested in the last round, all at once).  Rounds whatever the pairs per ray, 3 to 10 of
#   them, or only where over 1000-2500 pairs would wait: tested leaf pairs fell to 3.0 and
#   exact tests to 1.47 a ray, but a round's ~100 NumPy calls cost as much (in one process:
#   1504 against 1512-1528 ns; 6 and 10 rounds ~1700 and ~1790 against ~1580);
# - each ray's own T_MIN floor instead of the batch's (camera and bounce rays share
#   batches): exact tests 1.94 -> 1.90 a ray, no measurable gain for one more gather a level.
# - no floor in the top's steps (their entries only decide which pairs survive): 9 % slower
#   in one process (1751 against 1602): the floor is also the ray's start (0 at least), and
#   without it every box behind a ray's origin along its line survives.
# - the exact rows padded to 16 fields and line-aligned (again, in one process: +34 ns a
#   ray), the plane table line-aligned (a leaf's 8 rows in one 128-byte pair: +10, noise).
# Small trees, W2's 482 tree spheres (session 8; CPU of the BVH's intersect calls inside a
# 240x135 10 spp render on one worker, ~250-265 ms by machine load, interleaved child
# processes, medians).  Kept: two-level steps (SMALL_STEP_LEVELS), leaves of 2 spheres
# (SPHERE_LEAF_SIZE), the sphere pass in place, float32_up_nonnegative, divmod_by.  Tried:
# - SMALL_STEP_LEVELS 3 (0 -> 1 -> 4 -> 7 at leaves of 4): 276 against 260 for 2 (1: 275);
#   the odd level last (0 -> 2 -> 4 -> 6 -> 7) instead of first: within noise;
# - TRAVERSAL_BATCH 4096: 289 against 261 (2048 slower still), 12288 or 16384: within noise.
#   A benchmark that replays recorded rays without the renderer's malloc thresholds
#   (render.py's mallopt) put 4096 12 % ahead: there every big temporary page-faulted;
# - LEAF_SIZE 3 (an incomplete tree): 287 against 264; 8: ~10 % slower; SPHERE_LEAF_SIZE 1:
#   270 against 244 (a single sphere's box culls less than its bounding sphere);
# - LEAF_ROUNDS_ABOVE 1: 260 against 247; 4 or 1000 (no rounds): within noise (243-249);
# - the leaves' octant columns looked up with mode="wrap" instead of one % K: "wrap" walks
#   each out-of-range index down by subtraction, per element and per row: 305 against 270;
# - the float32 ray table written in place instead of concatenated: 268 against 266;
# - small trees' boxes node-major ((K, 24) rows, the transposed copy in the subtraction):
#   in isolation 83 against 67 us for 6,000 pairs; 16-byte elements (a plane of four
#   descendants in one np.void, pairs then pair-major, the rays' numbers and bound gathered
#   four wide from a repeated table): the box gather fell from 54 to 18 us, but a whole
#   two-level step of 6,800 pairs in isolation took 158 against 156 us (with the pairs'
#   rays in random order, as the walk leaves them, 169 against 162);
# - the octant by np.packbits over the sign bits: 4x slower than three ors.
# Where the time goes there now (line profile): the outsized spheres' brute force ~20 %, the
# walk's steps ~35 % (half of it the gathers of the boxes), the leaves ~25 % (the sphere
# pass about half, the exact tests a third), each batch's root clip and float32 ray table
# ~12 %.  (np.minimum.at slows ~10x on arrays whose dtype is not NumPy's own float64
# instance, as unpickled ones are: a trap for such replays, not met in the renderer.)
# Session 8, second round (W2's 90 intersect batches of a 160x90 10 spp render, recorded and
# replayed through integ's and this tree's BVH._intersect in one process, batch by batch
# alternating, CPU per pass ~105-110 ms; and whole 240x135 renders on one worker).  Kept: the
# per-batch setup and end with the same arithmetic and fewer passes (the root clip in place,
# the octant from uint8 sign bits, best_idx in int32, no copies of o and d when every ray
# enters the root box (a fifth of the batches), the float32 ray table written in place, no
# escaped_at_inf pass over the outsized answer): -2.6 % a pass; renders: intersection 240
# against 246 ms, the whole render 366 against 372 (medians of 6).  Tried, not kept:
# - a float32 bounding-sphere pre-filter of the outsized spheres (sphere_slots' test over
#   (4, N), then brute force's exact test on the kept (ray, sphere) pairs, nearest per ray
#   as SlabFilter's pairs): hits identical, but 29-31 against 20-22 ms for the 90 batches'
#   brute force.  It keeps ~1.2 pairs a ray of 4 (the ground's line passes within its
#   radius of ~90 % of them, the balls' 4-19 %), and its own float32 pass over (4, N) costs
#   about as much as the float64 exact test it replaces, before the pairs' gathers;
# - nearest_root's two divisions by a bool mask (comparison and division ~26 us on (4, 8192),
#   in isolation): the mask made as float64 by the comparison (out=) and then divided by
#   ~28 (the division itself is ~0.55 ns an element); an integer-bits form that sends a
#   miss to inf, not NaN, is not the same numbers.
# Session 9 (W2's recorded intersect calls, /tmp/s9/rays_final_scene.pkl, replayed whole in
# their own order, camera rays and bounce rays apart, CPU ns a ray, fresh processes of the two
# trees alternating, medians of 5-8; the machine shared, +-5 % between runs).  In the render's
# order bounce rays cost ~1.1x camera rays (274 against 249), not the ~1.5x that the image's
# first 32k camera rays suggested (mostly sky, missing the tree).  Kept: the walk without the
# axes whose planes every node shares (shared_axes: 274 -> 249 bounce, 249 -> 224 camera), the
# sphere pass's far root against each ray's floor (253 -> 244 bounce, camera level).  Tried:
# - the outsized balls tested only by the rays entering their common padded box (the ground
#   still by every ray, first): 291 against 270 bounce, camera level.  The float64 box clip
#   (~45 us a batch) and a second brute-force call on the ~40 % of rays that enter
#   (~133 us for 3 spheres, its fixed ~30 us included) cost more than the (3, N) block
#   they replace (~220 us); the ground alone costs a third of the four (~115 of ~340 us);
# - the ground exactly and the balls through a float32 bounding-sphere pre-filter: 349, 421
#   and 628 against 382, 452 and 438 us for 8,192 bounce, mixed and camera rays, before
#   merging (camera rays keep ~1 pair a ray: the camera looks at the balls);
# - nearest_root by two np.where (no division by a bool mask): (4, 8192) float64 67 against
#   105 us in isolation, but 261 against 255 bounce in the replay (7 runs of 8 slower);
# - the first step's boxes broadcast as lo/hi planes (no gather of the root's octant column,
#   no take of the rays' rows): 254 against 256 bounce, 235 against 242 camera, then 272
#   against 273 and 262 against 263: within noise;
# - SMALL_STEP_LEVELS 3 (with two axes a step's boxes cost a third less): 282 against 268
#   bounce, 267 against 249 camera; TRAVERSAL_BATCH 16384: 256 against 253, 227 against 230;
# - the outsized brute force in 4,096- or 2,048-ray calls: 470 and 595 against 371 us for
#   8,192 rays; 16,384 or 32,768 at once: 444 and 568 a 8,192 (its temporaries leave L2).
# Session 9, second round (the same recorded calls; integ's BVH module and this one loaded in one
# process over the same primitives, whole replays alternating, CPU ns a ray, medians of 11-15:
# one process shows ~1 % where fresh processes differ by +-5 %).  Where the time goes (timers
# between the lines, bounce rays, ~240-290 ns a ray by load): the outsized brute force ~50
# (sphere_roots and the keys ~40: 21 float64 passes over (4, N), L2-bound); set-up ~45 and the
# root clip; the walk ~105 (the boxes' gather and subtraction 43, the kept pairs' bookkeeping
# 28, of which nonzero over (4, P) bools ~16 us a step, entry/leave 15, the rays' gather 9, the
# multiplication 8); the leaves ~50 (the sphere pass 26, the exact tests 13, after them 7.5).
# The line profiler misplaced much of the set-up (np.nextafter showed 84 us, is 25).  Kept,
# together (bounce 0.968, camera 0.986 of integ, 11 runs, faster in 10 of 11 pairs; fresh
# processes of /tmp/bvh4/bench.py, 10 each: 285.2 against 288.4 bounce, 270.2 against 271.1):
# a scalar t_max stays a scalar in _batched's batches (each batch then skips escaped_at_inf's
# np.where over its rays and brute force's copy of t_max), float32_floor instead of
# np.nextafter, the leaves' entries taken only for rounds, a step onto a complete tree's
# leaves giving node numbers (leaf_below), the shared axis's leave plane by a take, the sphere
# exact test through root keys (SphereSet.exact_t).  Tried, not kept:
# - the float32 ray table made for every ray and gathered once, four bytes an element, where
#   at least half of them enter the root box (no gathers of the float64 o, d and 1/d; the exact
#   tests reading them at their columns): 0.980 then 1.014 bounce, 0.996 and 1.004 camera;
# - sphere_roots with its three axes as one (3, M, N) array (5 calls fewer, the same numbers):
#   (4, 7000) float64 167-184 against 167-173 us, 1,700 pairs 17.4-18.0 against 16.5-17.6;
# - small trees' boxes node-major now that W2 walks two axes (a node's 16 planes, one 64-byte
#   line, gathered as rows; the transposed copy in the subtraction): 262-279 against 59-62 us
#   for 7,500 pairs (a 64-byte void gather no better).
# Session 10 (W2's cover scene: the BVH.intersect calls of a 600x338 1 spp render, 514,680 rays
# in calls of up to 65,536 as at W3's wavefront size, replayed in one process through the
# committed module and the changed one over the same primitives, alternating, CPU ns a ray,
# medians of 11-21; the replay calls render.tune_allocator as workers do: without it the same
# calls took ~25 % longer and every big temporary page-faulted).  Where the time goes (timers
# around each phase, ~216 ns a ray): the outsized brute force 48, the set-up and root clip 37,
# the walk's four two-level steps 84 (~0.76-1.05 pairs a ray each; the box gather ~0.55 ns a
# plane, ~1.5x its cost in isolation), the leaves 37 (the exact tests 9: 0.29 a ray, nearly all
# hits), the end 7.  Kept: TRAVERSAL_BATCH 16384 in batches of equal size (see there).  Tried:
# - the descendants' columns made for every pair ((2^levels, P) = first + rank) and the kept
#   ones taken, instead of k // pairs on the kept indices: 1.012, then 0.999 at 16384;
# - to_beat as a row of the walk's float32 ray table (one gather a step for a pair's origin,
#   reciprocals and bound): 0.997;
# - SPHERE_LEAF_SIZE 8 (three steps, a sphere pass over 8 slots): 1.110; SMALL_STEP_LEVELS 3
#   (0 -> 2 -> 5 -> 8): 1.067; TRAVERSAL_BATCH 24576: 1.021, 32768 (unequal batches): 1.044;
#   LEAF_ROUNDS_ABOVE 1000 (no leaf rounds): 0.995 (noise);
# - the outsized brute force in calls of 8,192 rays inside a 16,384-ray batch: 0.958 against
#   0.956 for one call.
# In isolation (12,000 pairs): gathering the 16 planes of one octant's 511 columns takes ~70 us,
# of all eight octants' ~104-128: rays sorted by octant would save ~3 ns a pair step, less than
# the sort and the un-permuting cost; and rows (one 64-byte line a pair) with a transposed copy
# stay slower than columns even with L2 evicted (70-77 against 56 us for 6,000 pairs).  cProfile
# (where_time_goes.py) puts ~0.1 s of a W2 render on float32_floor at 16,384-ray batches; timers
# around its lines in a plain render show 4.5 ms, as at 8,192: a profiler artefact.
# Where the time goes on the 1M terrain (session 5; per segment, ~2040 ns in the tree): the walk's slab tests ~640
# (gathers of the boxes ~400 of it), its pair bookkeeping ~80, the leaf box pass ~480 (3.75
# leaves of 8 slots a segment), the plane pass ~200 (5.4 slots), the exact tests ~270 (1.9,
# of which 1.1 hit: in leaf order a ray over the rough surface often meets a farther
# triangle before the nearer one).
# The plane pass of triangle slots (see _plane_tables) drops a slot whose plane the ray
# stays on one side of, by more than a margin, over its whole span in the triangle's box:
# PLANE_ROUNDING float32 epsilons of the tree's extent cover the pass's own arithmetic (a
# dozen roundings of terms up to ~5 extents) and the float32 ray and plane, and
# PLANE_EXACT epsilons of the scene's precision over the sine of the triangle's angle at
# v0 cover how far off its plane the exact (Moller-Trumbore) test may put a hit it
# accepts (its t is off by ~eps |o - v0| / (sin * |n.d|)).  Triangles thinner than
# PLANE_MIN_SINE get no plane (never dropped).  On the 1M terrain the pass drops about
# half the slots the box pass keeps (rays crossing a box above or below the surface,
# rays leaving a surface).
# Pads grow with the farthest ray origin (ROUNDING_PAD): in float32 scenes with huge spheres
# that is the reach of their far parts (the cover's ground: 2,000 units, box pads of 0.031 and
# bounding spheres of radius 0.2 + 4 x 0.031 = 0.32 around its balls of 0.2), while all but a
# few rays in a million start within 40 units of its origin.  Small trees therefore keep two
# sets of tables: their own, padded for rays whose origins lie within NEAR_EXTENT of the
# origin (the cover: pads of 3.9e-3), and ``far``'s, a copy of the tree padded for the whole
# extent, which walks the other rays (none in most batches).  A ray counts as near when every
# coordinate of its origin lies within NEAR_EXTENT / 2, so its distance is at most
# sqrt(3) / 2 NEAR_EXTENT.  The cover's recorded intersect calls (600x338 2 spp, replayed):
# ~5 % less CPU a ray (fewer boxes entered, ~half as many exact tests).
NEAR_EXTENT = FLOAT32_EXTENT
# ... in trees of at most this many nodes: the copy's octant tables cost ~1 KB a node (the
# cover's 511 nodes: 0.54 MB; here at most ~4.5 MB), which compile's memory estimate
# (render.COMPILE_BYTES_PER_PRIMITIVE) was not measured with.  Bigger trees keep one set.
NEAR_TABLES_NODES = 1 << 12
PLANE_ROUNDING = 256
PLANE_EXACT = 512
PLANE_MIN_SINE = 2.0 ** -10
PLANE_BUILD_CHUNK = 1 << 16  # slots per step of the planes' build (temporaries of a few MB)


def _entry_leave(near, far, floor, bound, clip_leave):
    """Where rays enter and leave boxes: the largest of ``near``'s three axes
    (and ``floor``: a row, one per pair, see _traverse's ``floors``) and the smallest of ``far``'s (and ``bound``, by
    ``clip_leave``), written in place into ``near[0]`` and ``far[0]`` (fewer
    and smaller temporaries: a level's pairs stay in cache, see
    TRAVERSAL_BATCH_BIG).  ``near``, ``far``: (axes, ...) slab distances."""
    entry, leave = near[0], far[0]
    for axis in range(1, near.shape[0]):  # three axes, or fewer where the walk shares planes (walk_axes)
        np.fmax(entry, near[axis], out=entry)
    np.fmax(entry, floor, out=entry)
    for axis in range(1, far.shape[0]):
        np.fmin(leave, far[axis], out=leave)
    clip_leave(leave, bound, out=leave)
    return entry, leave


def float32_up(x) -> np.ndarray:
    """``x`` in float32, rounded towards +inf (a bound that stays a bound)."""
    return np.nextafter(np.asarray(x).astype(np.float32), np.float32(np.inf))


_FLOAT32_INF_BITS = np.int32(0x7F800000)


def float32_up_nonnegative(x) -> np.ndarray:
    """``float32_up(x)`` for ``x >= +0`` (inf included; a NaN stays a NaN), the same numbers.

    The float32 above a non-negative one is the one whose bits, read as an
    integer, are one more (0 -> the least subnormal, the largest finite ->
    inf); inf stays inf and NaN stays NaN.  One integer add instead of
    ``np.nextafter``: ~5 against ~20-30 us for a batch's 7,000 rays.  Wrong for
    negative numbers (and -0.0): only for distances.
    """
    bits = np.asarray(x).astype(np.float32).view(np.int32)
    bits += bits != _FLOAT32_INF_BITS
    return bits.view(np.float32)


def float32_down(x) -> np.ndarray:
    """``x`` in float32, rounded towards -inf."""
    return np.nextafter(np.asarray(x).astype(np.float32), np.float32(-np.inf))


_FLOAT32_MAX = np.finfo(np.float32).max


def float32_floor(shift: np.ndarray) -> np.ndarray:
    """``float32_down(T_MIN - shift)`` for ``shift >= 0`` (finite; float64, or float32 in a
    float32 scene), the same numbers.

    ``np.nextafter`` costs ~3 ns an element (~25 us of a batch's 7,000 rays, this ~10):
    instead the float32 ``x`` of ``T_MIN - shift``, rounded to nearest, steps down by one
    unit in its bits, read as an integer: one less for ``x > 0``, one more for ``x < 0``
    and for -0 (its magnitude grows: -0 -> the least negative subnormal).  It is made as
    ``-(shift - T_MIN)``, which rounds to the same ``x`` (rounding is symmetric) but is -0,
    never +0, where ``shift == T_MIN`` (a difference near T_MIN never rounds to zero in
    float32 otherwise), and ``shift - T_MIN`` above float32's largest is clamped to it so
    that ``x`` steps down to -inf as ``np.nextafter``'s does, not past it into NaN.
    """
    x = np.subtract(shift, T_MIN).astype(np.float32)
    np.minimum(x, _FLOAT32_MAX, out=x)
    np.negative(x, out=x)
    bits = x.view(np.int32)
    bits -= (bits >> 31) | 1  # the sign bit spread: -1 for x < 0 (and -0), 0 above; | 1: +-1
    return x


def divmod_by(a: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.divmod(a, n)`` for non-negative integers ``a`` and a positive ``n``: the quotient
    by floor division (NumPy divides by one scalar with a multiplication and shifts,
    libdivide) and the remainder as ``a - q n``.  ``%`` and ``np.divmod`` divide element by
    element: 7,000 indices 18-24 us against 8."""
    quotient = a // n
    remainder = quotient * n
    np.subtract(a, remainder, out=remainder)
    return quotient, remainder


def line_aligned(a: np.ndarray) -> np.ndarray:
    """A C-ordered copy of ``a`` whose first element starts a cache line (CACHE_LINE bytes).

    A node-major table's rows are gathered cold, one random row at a time; rows of a
    multiple of 64 bytes then span no more lines than they must (a 192-byte row 16 bytes
    past a line spans four): cold gathers of such rows measured ~10 % faster.
    """
    raw = np.empty(a.nbytes + CACHE_LINE, dtype=np.uint8)
    start = -raw.ctypes.data % CACHE_LINE
    out = raw[start:start + a.nbytes].view(a.dtype).reshape(a.shape)
    np.copyto(out, a)
    return out


def build_levels(lo: np.ndarray, hi: np.ndarray, members: np.ndarray, leaf_size: int = LEAF_SIZE) -> dict:
    """A median-split tree over the boxes ``lo, hi (3, M)`` of ``members``, built level by level.

    Nodes are numbered breadth-first (the root is 0) and siblings are
    adjacent, so an interior node stores only its left child.  The nodes of a
    level own consecutive runs (``first``, ``count``) of the permutation
    ``order``; a level sorts each run by the box centres along its widest
    axis in one ``argsort`` over every run at once (keyed by run number plus
    the normalised centre), and halves it.  No Python loop runs over nodes.

    Returns
    -------
    dict with ``lo, hi (3, K)`` node boxes, ``child (K,)`` (left child, or -1
    for a leaf), ``first, count (K,)`` (a leaf's run of ``order``; count 0 for
    interior nodes), ``order (M,)`` and ``first_leaf_depth``.
    """
    centre = 0.5 * (lo + hi)
    order = np.asarray(members, dtype=np.int64).copy()
    first = np.zeros(1, dtype=np.int64)
    count = np.array([order.size], dtype=np.int64)
    levels = []
    first_leaf_depth = None
    base = 0  # index of the level's first node
    depth = 0
    while first.size:
        nodes = first.size
        start = np.cumsum(count) - count  # each run's start in the level's concatenation
        run = np.repeat(np.arange(nodes), count)
        position = first.take(run) + (np.arange(run.size) - start.take(run))
        element = order.take(position)
        box_lo = np.minimum.reduceat(lo.take(element, axis=1), start, axis=1)
        box_hi = np.maximum.reduceat(hi.take(element, axis=1), start, axis=1)
        leaf = count <= leaf_size
        inner = np.flatnonzero(~leaf)
        child = np.full(nodes, -1, dtype=np.int64)
        child[inner] = base + nodes + 2 * np.arange(inner.size)
        levels.append((box_lo, box_hi, child, np.where(leaf, first, 0), np.where(leaf, count, 0)))
        if first_leaf_depth is None and leaf.any():
            first_leaf_depth = depth
        if inner.size == 0:
            break
        # split every interior run at its median along its widest axis
        keep = np.flatnonzero(~leaf.take(run))
        rank = np.cumsum(~leaf) - 1
        run_i = rank.take(run.take(keep))
        position_i, element_i = position.take(keep), element.take(keep)
        count_i = count.take(inner)
        start_i = np.cumsum(count_i) - count_i
        c = centre.take(element_i, axis=1)
        c_lo = np.minimum.reduceat(c, start_i, axis=1)
        c_hi = np.maximum.reduceat(c, start_i, axis=1)
        span = c_hi - c_lo
        axis = np.argmax(span, axis=0)
        axis_e = axis.take(run_i)
        key = c[axis_e, np.arange(run_i.size)] - c_lo[axis, np.arange(inner.size)].take(run_i)
        width = span[axis, np.arange(inner.size)]
        key /= np.where(width > 0, width, 1.0).take(run_i)  # in [0, 1] within its run
        ranked = np.argsort(run_i + 0.5 * key, kind="stable")  # runs stay in order, each sorted
        order[position_i] = element_i.take(ranked)
        half = count_i // 2
        first_i = first.take(inner)
        first = np.stack((first_i, first_i + half), axis=1).ravel()
        count = np.stack((half, count_i - half), axis=1).ravel()
        base += nodes
        depth += 1
    lo_all, hi_all, child, first_all, count_all = (np.concatenate(parts, axis=-1) for parts in zip(*levels))
    return dict(lo=lo_all, hi=hi_all, child=child, first=first_all, count=count_all, order=order,
                first_leaf_depth=first_leaf_depth if first_leaf_depth is not None else 0)


class BVH:
    """Same interface as :class:`~wavefront.shapes.Primitives` (brute force), and the same answers."""

    def __init__(self, primitives: Primitives, extent: float | None = None):
        """``extent``: how far from the origin rays may start (default: the
        tree's own extent); boxes are padded by brute force's rounding there."""
        self.primitives = primitives
        self.extent = extent
        self.material_idx = primitives.material_idx
        self.bound_center, self.bound_radius = primitives.bounding_sphere()
        radius = self.bound_radius
        order = np.argsort(-radius, kind="stable")[:MAX_OUTSIZED]
        order = order[radius[order] > OUTSIZED * np.median(radius)]
        if order.size:
            rest = np.ones(radius.size, dtype=bool)
            rest[order] = False
            if rest.any():
                lo = (self.bound_center[:, rest] - radius[rest]).min(axis=1)
                hi = (self.bound_center[:, rest] + radius[rest]).max(axis=1)
                order = order[radius[order] > OUTSIZED_SHARE * np.linalg.norm(hi - lo)]
        self.outsized = np.sort(order)
        inside = np.ones(len(primitives), dtype=bool)
        inside[self.outsized] = False
        self.outsized_set = primitives.subset(self.outsized)
        self.leaf_rounds_above = LEAF_ROUNDS_ABOVE  # tests set 0 to exercise the rounds on small trees
        in_tree = int(inside.sum())
        spheres = all(kind.name == "sphere" for kind in primitives.kinds)
        self.leaf_size = BIG_LEAF_SIZE if in_tree > BIG_TREE else \
            SPHERE_LEAF_SIZE if spheres and in_tree <= SPHERE_TREE else LEAF_SIZE
        self._build(np.flatnonzero(inside))

    def __len__(self) -> int:
        return len(self.primitives)

    def surface(self, origin, direction, t, idx, uv: bool = False, time=None):
        return self.primitives.surface(origin, direction, t, idx, uv, time)

    @property
    def moving(self) -> bool:
        return self.primitives.moving

    # -- construction ------------------------------------------------------

    def _build(self, members: np.ndarray) -> None:
        lo, hi = self.primitives.bounds()
        self.empty = members.size == 0
        if self.empty:  # everything is outsized: a single empty leaf that no ray reaches
            members = np.zeros(0, dtype=np.int64)
            lo = hi = np.zeros((3, 1))
            tree = dict(lo=np.zeros((3, 1)), hi=np.zeros((3, 1)), child=np.array([-1]), first=np.array([0]),
                        count=np.array([0]), order=members, first_leaf_depth=0)
        else:
            tree = build_levels(lo, hi, members, self.leaf_size)
        boxes = np.concatenate((tree["lo"], tree["hi"]))  # (6, K): lo xyz, hi xyz
        self.child, self.first, self.count, self.order = tree["child"], tree["first"], tree["count"], tree["order"]
        self.first_leaf_depth = tree["first_leaf_depth"]
        # all leaves at first_leaf_depth (a median split of 2^n leaves' worth, as the 1M terrain):
        # the walk then needs no per-pair leaf test there
        self.complete = self.child.size == (2 << self.first_leaf_depth) - 1
        # big trees walk subtrees of SUBTREE_LEVELS levels nearest-first (tests set it on small trees)
        self.subtree_depth = self.first_leaf_depth - SUBTREE_LEVELS if self.child.size > NODE_MAJOR_NODES else None
        # each leaf's primitives in a fixed-width table, padded with unhittable NaN spheres
        k = self.child.size
        self.leaf_slot = np.full((self.leaf_size, k), -1, dtype=np.int64)
        for j in range(self.leaf_size):
            has = self.count > j
            self.leaf_slot[j, has] = self.order.take(self.first[has] + j)
        # (K * leaf_size,): slot j of node k at k * leaf_size + j, a leaf's slots side by side, so the
        # few slots of a (ray, leaf) pair that pass the box test read one or two cache lines here and
        # in the plane table (at j * K + k they lay K apart, a miss and often a TLB miss each: on
        # the 1M terrain the plane pass cost ~10 % more)
        self.leaf_primitive = np.maximum(self.leaf_slot, 0).T.ravel()
        boxes = boxes.astype(np.float64)
        self.far = None
        self._build_traversal_tables(boxes)
        tree_extent = float(np.abs(boxes).max())
        rays_extent = tree_extent if self.extent is None else max(tree_extent, float(self.extent))
        if not self.empty and self.child.size <= NEAR_TABLES_NODES and \
                self._pad(tree_extent, min(rays_extent, NEAR_EXTENT)) < self._pad(tree_extent, rays_extent):
            # near and far tables (see NEAR_EXTENT): the tables just built, at the full pad,
            # serve the far rays as a copy of this tree; this tree's own are rebuilt at the
            # near pad
            self.far = copy.copy(self)
            self._build_traversal_tables(boxes, near=True)

    def _pad(self, tree_extent: float, rays_extent: float) -> float:
        """The boxes' pad for rays starting within ``rays_extent`` of the origin (see BOX_PAD)."""
        if any(getattr(kind, "anchored", False) for kind in self.primitives.kinds):
            # an anchored set reaches past FLOAT32_EXTENT (its outsized spheres, whatever the
            # tree's own extent): pads of at least 3.9e-3, several T_MIN, keep every pair whose
            # ray starts near its sphere (see the module docstring), also without an extent
            rays_extent = max(rays_extent, FLOAT32_EXTENT)
        pad = max(BOX_PAD * tree_extent, ROUNDING_PAD * float(np.finfo(self.primitives.dtype).eps) * 2 * rays_extent)
        # flat primitives accept hits up to their own (much smaller) pad outside their boxes
        return pad + self.primitives.pad + float(np.finfo(np.float32).tiny)

    def _build_traversal_tables(self, boxes: np.ndarray, near: bool = False) -> None:
        """float32 child boxes per octant: ``octant_boxes (12, 8K)``; ``boxes`` is (6, K) float64.

        Column ``octant * K + node`` holds node's two children; rows are the
        x, y, z planes the octant's rays enter through (left child, right
        child for each axis), then the planes they leave through (rows
        ``(enter/leave, axis, child)``, so that the slab test's reductions
        over axes run on contiguous rows).  ``octant_left (8K,)`` gives the left
        child's column in the same octant; the right child's is the next.
        Node-major trees keep one "octant" (lo then hi planes, ``(K, 12)``
        rows) and ``descendant_boxes``; see NODE_MAJOR_NODES and STEP_LEVELS.
        """
        k = self.child.size
        f32 = np.float32
        tree_extent = float(np.abs(boxes).max())
        rays_extent = tree_extent if self.extent is None else max(tree_extent, float(self.extent))
        pad = self._pad(tree_extent, min(rays_extent, NEAR_EXTENT) if near else rays_extent)
        # the root box, padded alike, clips rays in the scene's precision
        self.root_box = np.concatenate((boxes[:3, :1] - pad, boxes[3:, :1] + pad))
        # each leaf slot's own primitive box, padded like the nodes' and rounded outwards, for
        # the leaf test's float32 pass: a hit of the exact test lies in its primitive's box
        # exactly as it lies in every ancestor's, so this culls nothing a node box would
        # keep.  Rows are lo x, y, z then hi x, y, z, leaf_size slots each; NaN in padding
        # slots fails the test (see test_leaves)
        real = self.leaf_slot >= 0
        slot = np.maximum(self.leaf_slot, 0)
        # Spheres-only trees keep the bounding-sphere pass instead (for a ball it is tighter
        # than its box: W2 rendered 9 % slower with boxes): the ray's line must pass within
        # the padded radius of the centre, LEAF_PAD box pads covering its own rounding.
        self.sphere_leaves = all(kind.name == "sphere" for kind in self.primitives.kinds)
        if self.sphere_leaves:
            center = self.bound_center[:, slot]
            self.leaf_center32 = np.where(real, center, np.nan).astype(f32)  # (3, leaf_size, K)
            reach = self.bound_radius[slot] + LEAF_PAD * pad
            self.leaf_reach32 = float32_up(np.where(real, reach, np.nan))  # (leaf_size, K)
        else:
            prim_lo, prim_hi = self.primitives.bounds()
            slot_lo = np.where(real, float32_down(prim_lo[:, slot] - pad), np.nan)  # (3, leaf_size, K)
            slot_hi = np.where(real, float32_up(prim_hi[:, slot] + pad), np.nan)
            self.leaf_boxes32 = np.concatenate((slot_lo, slot_hi)).astype(f32).reshape(6 * self.leaf_size, k)
        self.leaf_planes32 = None if self.sphere_leaves else self._plane_tables(tree_extent, pad)
        lo, hi = float32_down(boxes[:3] - pad), float32_up(boxes[3:] + pad)  # rounded outwards
        left = np.maximum(self.child, 0)
        right = left + (self.child >= 0)
        self.node_major = k > NODE_MAJOR_NODES
        # Node-major trees store one table: eight octant copies of 8K rows made the walk's
        # working set 8 times bigger (rays of every octant leave a terrain), for a min and a
        # max per axis on pair-minor columns; the 1M terrain's tables 100 MB -> 12.6 MB.
        self.octants = 1 if self.node_major else 8
        # Axes on which every node's box has the root's two planes (W2's carpet: every ball
        # touches the ground and is as tall as the others) are left out of small trees' walk:
        # there every node's slab is the root's, the same float32 numbers, so a ray leaves it
        # where it leaves the root's (folded into the ray's bound once, see _traverse) and
        # enters it no later than the floor (the traversal's rays start in the root box, up to
        # rounding, which can only make entries smaller and so keeps more).  W2 walks two
        # axes of three: a third fewer planes gathered and slabs computed a level.
        shared = [axis for axis in range(3) if (lo[axis] == lo[axis, 0]).all() and (hi[axis] == hi[axis, 0]).all()]
        self.shared_axes = [] if self.node_major or len(shared) == 3 else shared
        self.walk_axes = [axis for axis in range(3) if axis not in self.shared_axes]
        self.shared_planes = {axis: np.array([hi[axis, 0], lo[axis, 0]]) for axis in self.shared_axes}  # leave by, sign +/-
        axes = len(self.walk_axes)
        tables = np.empty((2, axes, 2, self.octants, k), dtype=f32)  # enter/leave (lo/hi), axis, child, octant, node
        for octant in range(self.octants):
            for row, axis in enumerate(self.walk_axes):
                negative = (octant >> axis) & 1
                enter, leave = (hi, lo) if negative else (lo, hi)
                for side, child in enumerate((left, right)):
                    tables[0, row, side, octant] = enter[axis, child]
                    tables[1, row, side, octant] = leave[axis, child]
        self.octant_boxes = tables.reshape(4 * axes, self.octants * k)
        offset = np.arange(self.octants)[:, None] * k
        self.octant_left = (left + offset).ravel()  # the right child is the next column
        self.octant_is_leaf = np.tile(self.count > 0, self.octants)
        self.top_boxes = {}  # levels stepped -> the first nodes' boxes as columns (see TOP_NODES)
        # Small trees step SMALL_STEP_LEVELS full levels at a time too, from per-octant tables of
        # a node's descendants (rows (enter/leave, axis, descendant), column octant * K + node,
        # as octant_boxes), and octant_below[levels] gives the first descendant's column.
        self.octant_descendants, self.octant_below, self.leaf_below = {}, {}, {}
        for levels in range(2, (1 if self.node_major else SMALL_STEP_LEVELS) + 1):
            inner = (1 << max(self.first_leaf_depth - levels + 1, 0)) - 1  # nodes `levels` full levels above the first leaves
            if inner == 0:
                break
            width = 1 << levels
            below = width * np.arange(inner)[None, :] + (width - 1) + np.arange(width)[:, None]  # (width, inner)
            table = np.zeros((2, axes, width, self.octants, k), dtype=f32)
            for octant in range(self.octants):
                for row, axis in enumerate(self.walk_axes):
                    enter, leave = (hi, lo) if (octant >> axis) & 1 else (lo, hi)
                    table[0, row, :, octant, :inner] = enter[axis, below]
                    table[1, row, :, octant, :inner] = leave[axis, below]
            self.octant_descendants[levels] = table.reshape(2 * axes * width, self.octants * k)
            first_below = np.zeros((self.octants, k), dtype=np.int64)
            first_below[:, :inner] = offset + width * np.arange(inner) + (width - 1)
            self.octant_below[levels] = first_below.ravel()
            leaf_below = np.zeros((self.octants, k), dtype=np.int64)  # the same in node numbers
            leaf_below[:, :inner] = width * np.arange(inner) + (width - 1)
            self.leaf_below[levels] = leaf_below.ravel()
        if self.node_major:  # the same numbers, one row per node (see NODE_MAJOR_NODES)
            self.octant_boxes = np.ascontiguousarray(self.octant_boxes.T)  # (K, 12)
            # Several levels at a step where all are full: node n's descendants `levels`
            # down are 2^levels n + 2^levels - 1 + g (g < 2^levels), (lo/hi, axis, 2^levels)
            # per row.  A grandchild's box lies in its parent's, so testing the four at once
            # culls what two steps did; it tests ~10 % fewer boxes than two steps (60 % of
            # children survive on the 1M terrain) with one gather and one set of pair
            # bookkeeping instead of 1 + 1.2.
            self.descendant_boxes = {}
            for levels in range(2, STEP_LEVELS + 1):
                inner = (1 << max(self.first_leaf_depth - levels + 1, 0)) - 1  # nodes `levels` full levels above the first leaves
                width = 1 << levels
                below = width * np.arange(inner)[:, None] + (width - 1) + np.arange(width)  # (inner, width)
                self.descendant_boxes[levels] = line_aligned(
                    np.stack((lo[:, below], hi[:, below])).transpose(2, 0, 1, 3).reshape(inner, 6 * width))
            # the top of the tree as columns too (see TOP_NODES): {levels: (6 * 2^levels, top)}
            self.top_boxes = {levels: np.ascontiguousarray(table[:TOP_NODES].T)
                              for levels, table in self.descendant_boxes.items()}
            self.top_boxes[1] = np.ascontiguousarray(self.octant_boxes[:TOP_NODES].T)
            if self.sphere_leaves:
                self.leaf_rows32 = np.ascontiguousarray(np.concatenate(
                    (self.leaf_center32.reshape(3 * self.leaf_size, k), self.leaf_reach32)).T)  # (K, 4 leaf_size)
                self.leaf_center32 = self.leaf_reach32 = None
            else:
                self.leaf_boxes32 = line_aligned(self.leaf_boxes32.T)  # (K, 6 leaf_size)

    def _plane_tables(self, tree_extent: float, pad: float) -> np.ndarray | None:
        """Each triangle slot's plane, scaled by its margin: ``(leaf_size * K, 4)``
        float32 rows ``n / m, (n . v0) / m`` (slot j of node k at k * leaf_size + j), NaN
        for other kinds and padding slots (NaN never drops a slot).

        The plane is the one the exact test sees (the stored v0, e1, e2); with it
        scaled by the margin ``m`` the pass compares against 1.  ``m`` adds to the
        roundings (see PLANE_ROUNDING) the box pad: the computed entry and exit of a
        slot's box hold any hit's t to within it.
        """
        kinds = [(i, kind) for i, kind in enumerate(self.primitives.kinds) if kind.name == "triangle"]
        if not kinds:
            return None
        planes = np.full((self.leaf_slot.size, 4), np.nan, dtype=np.float32)
        slot = self.leaf_slot.T.ravel()
        kind_of = self.primitives.kind_of(np.maximum(slot, 0))
        for i, kind in kinds:
            sel = np.flatnonzero((slot >= 0) & (kind_of == i))
            for part in np.array_split(sel, max(1, -(-sel.size // PLANE_BUILD_CHUNK))):  # bounded temporaries
                rows = np.take(kind.packed, slot.take(part) - self.primitives.offsets[i], axis=0)
                v0, e1, e2 = (rows[:, j:j + 3].astype(np.float64) for j in (0, 3, 6))
                n = np.cross(e1, e2)
                area = np.linalg.norm(n, axis=1)
                sine = area / (np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1))
                n /= area[:, None]
                margin = tree_extent * (PLANE_ROUNDING * float(np.finfo(np.float32).eps) +
                                        PLANE_EXACT * float(np.finfo(kind.dtype).eps) / sine) + pad
                margin[~(sine >= PLANE_MIN_SINE)] = np.nan  # no plane
                planes[part, :3] = n / margin[:, None]
                planes[part, 3] = (n * v0).sum(axis=1) / margin
        return planes

    # -- traversal -----------------------------------------------------------

    def intersect(self, origin, direction, t_max=np.inf, time=None) -> Hits:
        """Nearest hit with ``T_MIN < t < t_max`` for every ray (see :meth:`Primitives.intersect`).

        A moving sphere's boxes hold it over the whole interval [0, 1]
        (``SphereSet.bounds``); its exact test places it at each ray's ``time``."""
        return self._batched(self._intersect, origin, direction, t_max, time)

    def occluded(self, origin, direction, t_max, time=None) -> np.ndarray:
        """Any hit with ``T_MIN < t < t_max``: a ray leaves the traversal at its first hit."""
        return self._batched(self._occluded, origin, direction, t_max, time)

    def _batched(self, query, origin, direction, t_max, time=None):
        n = origin.shape[1]
        batch = TRAVERSAL_BATCH_BIG if self.node_major else TRAVERSAL_BATCH
        if n <= batch:
            return query(origin, direction, t_max, time)
        batch = -(-n // -(-n // batch))  # as few batches as `batch` allows, of equal sizes (see TRAVERSAL_BATCH)
        # a scalar t_max (the paths' rays: inf) stays one, so that each batch's answer skips
        # escaped_at_inf's np.where over its rays, and brute force its copy of t_max (~20 us
        # a batch of 8,192; W2's renders pass every bounce's rays at once)
        if np.ndim(t_max) == 0:
            limit = lambda a: t_max  # noqa: E731
        else:
            t_max = np.broadcast_to(np.asarray(t_max, dtype=origin.dtype), (n,))
            limit = lambda a: t_max[a:a + batch]  # noqa: E731
        parts = [query(origin[:, a:a + batch], direction[:, a:a + batch], limit(a),
                       None if time is None else time[a:a + batch]) for a in range(0, n, batch)]
        if isinstance(parts[0], Hits):
            return Hits(np.concatenate([h.t for h in parts]), np.concatenate([h.primitive_idx for h in parts]))
        return np.concatenate(parts)

    def _intersect(self, origin, direction, t_max, time=None) -> Hits:
        n = origin.shape[1]
        limit = np.broadcast_to(np.asarray(t_max, dtype=origin.dtype), (n,))
        # outsized primitives first: their hits bound the traversal (none: skip brute force's
        # passes over the rays, 6 % of a terrain's camera rays)
        # (one call of brute force's own: a batch is at most TRAVERSAL_BATCH rays against at most
        # MAX_OUTSIZED primitives, which its chunks of rays would only split into more calls)
        # (first.t is t_max, not inf, where nothing was hit: the minimum below takes the limit
        # there either way, and from_first reads only hits; escaped_at_inf's np.where over the
        # batch was ~2 ms of W2's ~270 ms of intersection)
        first = self.outsized_set._intersect(origin, direction, t_max, time, escaped_inf=False) \
            if len(self.outsized) else None
        best_t = limit.copy() if first is None else np.minimum(first.t, limit)
        found = self._walk(origin, direction, limit, best_t, time=time)  # lowers best_t to the tree's hits
        # int32 throughout, what Hits holds (every scene-wide index fits): no final cast, and
        # the sentinel's correction in int32 (~5 us a batch of 8,192 rays against ~10)
        none = np.int32(len(self.primitives))  # sentinel above every index, so np.minimum keeps real ones
        best_idx = np.full(n, none, dtype=np.int32)
        if first is not None:
            from_first = ((first.primitive_idx >= 0) & (first.t == best_t)).nonzero()[0]
            # (mode="wrap" on indices valid by construction, as in _traverse: from_first keeps hits only, no -1)
            best_idx[from_first] = self.outsized.take(first.primitive_idx.take(from_first, mode="wrap"), mode="wrap")
        if found:
            ray, t, prim = (np.concatenate(a) for a in zip(*found))
            winner = (t == best_t.take(ray, mode="wrap")).nonzero()[0]
            # ties go to the lowest primitive index, as in brute force (values cast to the
            # target's int32 first: ufunc.at's fast path needs matching types)
            np.minimum.at(best_idx, ray.take(winner, mode="wrap"), prim.take(winner, mode="wrap").astype(np.int32))
        missed = best_idx == none
        best_idx -= np.multiply(missed, none + np.int32(1), dtype=np.int32)  # the sentinel becomes -1
        return Hits(escaped_at_inf(best_t, ~missed, t_max) if np.ndim(t_max) or t_max != np.inf else best_t,
                    best_idx)

    def _occluded(self, origin, direction, t_max, time=None) -> np.ndarray:
        n = origin.shape[1]
        limit = np.broadcast_to(np.asarray(t_max, dtype=origin.dtype), (n,))
        blocked = self.outsized_set._occluded(origin, direction, limit, time) if len(self.outsized_set) else \
            np.zeros(n, dtype=bool)
        rest = (~blocked).nonzero()[0]
        if rest.size:
            # (mode="wrap" on indices valid by construction: see _traverse)
            o, d = origin.take(rest, axis=1, mode="wrap"), direction.take(rest, axis=1, mode="wrap")
            lim = limit.take(rest, mode="wrap")
            t = None if time is None else time.take(rest, mode="wrap")
            found = self._walk(o, d, lim, lim.copy(), any_hit=True, time=t)
            if found:
                blocked[rest.take(np.concatenate([f[0] for f in found]), mode="wrap")] = True
        return blocked

    def _walk(self, origin, direction, limit, best_t, any_hit: bool = False, time=None) -> list:
        """:meth:`_traverse` over both sets of tables: the near rays through
        this tree's, the far ones (see NEAR_EXTENT) through ``self.far``'s,
        ``best_t`` lowered for both; what they found, numbered by this call's rays."""
        far = self._far_rays(origin)
        found = self._traverse(origin, direction, limit, best_t, any_hit=any_hit, time=time, skip=far)
        if far is not None:
            far = far.nonzero()[0]
            far_t = best_t.take(far)
            far_found = self.far._traverse(gather(origin, far), gather(direction, far), limit.take(far), far_t,
                                           any_hit=any_hit, time=None if time is None else time.take(far))
            best_t[far] = far_t
            found += [(far.take(ray), *rest) for ray, *rest in far_found]
        return found

    def _far_rays(self, origin) -> np.ndarray | None:
        """Which rays start beyond NEAR_EXTENT / 2 on some axis (bool (N,)), or None if none
        does or the tree has one set of tables."""
        if self.far is None:
            return None
        bound = NEAR_EXTENT / 2
        if origin.max(initial=-np.inf) <= bound and origin.min(initial=np.inf) >= -bound:  # the usual batch
            return None
        far = np.abs(origin) > bound
        return far[0] | far[1] | far[2]

    def _traverse(self, origin, direction, limit, best_t, any_hit: bool = False, time=None, skip=None) -> list:
        """Walk the tree for the rays that enter its root box (and are not ``skip``'s).

        Lowers ``best_t`` in place to each ray's nearest tree hit and returns
        a list of ``(ray, t, primitive)`` candidate hits; per ray, those with
        ``t == best_t`` are the nearest.  With ``any_hit`` a ray leaves the
        walk at its first hit (which need not be its nearest).
        """
        if self.empty:
            return []
        # Every gather here takes with mode="wrap": its indices are valid by construction (ray
        # numbers and positions from nonzero() over the arrays they index, node numbers and
        # columns from the tree's own tables), and "wrap" skips the default mode's bounds check,
        # ~25 % of a big take (60 Ki lookups ~23 us against ~30).  Over the walk's per-pair and
        # per-ray takes, the leaves' and the hits': ~0.8 % of W2's intersection time (a replay
        # of W2's cover-scene calls, 217 ns a ray against 219).  No sentinel reaches a take.
        f32 = np.float32
        # the root clip with the same arithmetic in place: (3, N) temporaries of 8,192 rays
        # leave cache, and each fresh one is another pass over memory
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / direction
            t0 = np.subtract(self.root_box[:3], origin)
            t0 *= inv
            t1 = np.subtract(self.root_box[3:], origin)
            t1 *= inv
        hi = np.fmax(t0, t1)
        lo = np.fmin(t0, t1, out=t0)
        near, far = lo[0], hi[0]
        np.fmax(near, lo[1], out=near)
        np.fmax(near, lo[2], out=near)
        np.fmin(far, hi[1], out=far)
        np.fmin(far, hi[2], out=far)
        enters = near <= far
        enters &= far >= T_MIN
        enters &= near <= best_t
        if skip is not None:
            enters &= ~skip
        ray_ids = enters.nonzero()[0]
        if ray_ids.size == 0:
            return []
        # Per-ray arrays stay indexed by the batch's own ray numbers, the rays that miss the
        # root box included (their numbers, NaN or inf among them, are computed and never
        # read: the walk starts from ray_ids only).  Compacting the ~80 % of W2's rays that
        # enter cost gathers of o, d, 1/d (float64), best_t and limit, a scatter of the hits'
        # distances back into best_t and a gather of the found rays' numbers: more than the
        # ~20 % more elements of the passes below (W2's cover scene at W3's wavefront size,
        # with the floor below: ~5 ns a ray of ~230, 2.5 %).  ``nearest`` is best_t itself,
        # lowered in place.
        o, d, nearest = origin, direction, best_t
        # The traversal's ray starts where it enters the root box, so its t
        # is the true t minus `shift`; no box behind that point holds a hit,
        # which is why box entries are clamped at 0 below.
        shift = np.maximum(near, 0.0, out=near)
        rays = np.empty((6, origin.shape[1]), dtype=f32)
        # over, invalid: the rays that miss the root box (shift inf or NaN; see above), and
        # 1/d beyond float32 becomes inf, which the slab test handles
        with np.errstate(over="ignore", invalid="ignore"):
            start = d * shift
            start += o  # o + shift d (addition commutes exactly)
            np.copyto(rays[:3], start, casting="same_kind")
            np.copyto(rays[3:], inv, casting="same_kind")
            # the best hit so far in the traversal's frame (nearest >= shift: rays whose root
            # box entry lies beyond their best hit were left out above)
            to_beat = float32_up_nonnegative(nearest - shift)
        # the walk's rays: the origins' and reciprocals' rows of its axes only
        walk_rows = self.walk_axes + [3 + axis for axis in self.walk_axes]
        walk_rays = rays if len(walk_rows) == 6 else rays[walk_rows]
        # where each ray leaves the slabs every node shares (shared_axes): the walk computes no
        # leave on those axes, and a ray's bound stands for it (the same float32 numbers the
        # walk would compute on them at every node: the planes the octant leaves by)
        cap = None
        for axis in self.shared_axes:
            # the plane the ray leaves by, picked by its sign bit (a take from two: ~5 us a batch, np.where ~9)
            leave = self.shared_planes[axis].take(np.signbit(d[axis]).view(np.uint8), mode="wrap")
            leave -= rays[axis]
            leave *= rays[3 + axis]
            cap = leave if cap is None else np.fmin(cap, leave, out=cap)
        if cap is not None:
            np.fmin(to_beat, cap, out=to_beat)
        found = []
        # one limit for every ray (a scalar t_max broadcast): compared as the scalar, no gather
        limit_one = limit[0] if limit.ndim == 1 and limit.strides[0] == 0 else None

        k = self.child.size
        axes = len(self.walk_axes)
        d32 = d.astype(f32) if self.sphere_leaves or self.leaf_planes32 is not None else None

        def test_leaves(ray, node, entries, at, rays_walking):
            """Test (ray, leaf) pairs, each ray's nearest leaves first.

            ``entries.take(at)`` is where each pair's ray enters its leaf's box
            (taken only where rounds are made: most small trees' calls make none).  Every
            round tests each ray's nearest remaining leaves (ties included)
            and then drops the pairs whose leaf the ray enters beyond its
            best hit so far, the same cull as the node boxes': a ray over a
            terrain crosses many leaf boxes behind its hit, and testing them
            all at once found its hit only after testing them all.  After
            LEAF_ROUNDS (BIG_LEAF_ROUNDS) rounds, or once fewer than LEAF_ROUNDS_ABOVE pairs per
            ray are left, what is left is tested at once.
            """
            rounds = BIG_LEAF_ROUNDS if self.node_major else LEAF_ROUNDS
            entry = None
            for round_ in range(rounds):
                if round_ < rounds - 1 and ray.size > self.leaf_rounds_above * rays_walking:
                    entry = entries.take(at, mode="wrap") if entry is None else entry
                    first = np.full(origin.shape[1], np.inf, dtype=f32)
                    np.minimum.at(first, ray, entry)
                    now = entry <= first.take(ray, mode="wrap")
                    test_slots(ray[now], node[now])
                    later = (~now).nonzero()[0]
                else:
                    test_slots(ray, node)
                    break
                ray, node = ray.take(later, mode="wrap"), node.take(later, mode="wrap")
                entry = entry.take(later, mode="wrap")
                alive = (entry <= to_beat.take(ray, mode="wrap")).nonzero()[0]
                if alive.size == 0:
                    break
                ray, node = ray.take(alive, mode="wrap"), node.take(alive, mode="wrap")
                entry = entry.take(alive, mode="wrap")

        def sphere_slots(ray, node):
            """The bounding-sphere pass of spheres-only trees: a float32 test in
            the traversal's frame over all (leaf_size, P) (ray, sphere) slots
            keeps those whose line passes within a padded bounding radius and
            whose span in that padded sphere overlaps [T_MIN, to_beat] (T_MIN in
            the ray's own frame, T_MIN - shift in the traversal's); padding slots
            are NaN and never kept.

            The span's far end is the padded sphere's far root, ``h + sqrt(reach^2
            - |l|^2)``: a ray leaving a ball starts on it with that root at about 0,
            below the floor (T_MIN), and is not tested against it again (61 % of the
            exact tests of W2's bounce rays were such).  Conservative as the rest of
            the pass: the LEAF_PAD pads in ``reach^2 - |l|^2`` (about 2 reach LEAF_PAD
            pads more than the true sphere's) put the computed root past the true one by
            about LEAF_PAD pads, more than the float32 rounding of ``h`` and ``|l|``.  A far
            root that is NaN (squares of a radius past ~1.8e19 overflow float32 to inf, and
            inf - inf) keeps its slot: the pass drops only what it can show is behind the
            floor, and the exact test decides."""
            if self.node_major:
                rows = gather_columns(self.leaf_rows32, node)  # (4 leaf_size, P)
                center, reach = rows[:3 * self.leaf_size].reshape(3, self.leaf_size, -1), rows[3 * self.leaf_size:]
            else:
                center = self.leaf_center32.take(node, axis=2, mode="wrap")  # (3, leaf_size, P)
                reach = self.leaf_reach32.take(node, axis=1, mode="wrap")  # padded radius
            # in place where the numbers allow: each fresh (leaf_size, P) temporary is another
            # pass over memory (the same arithmetic with four fewer measured ~10 % faster)
            oc = center
            oc -= rays[:3].take(ray, axis=1, mode="wrap")[:, None, :]  # the origins only
            dr = d32.take(ray, axis=1, mode="wrap")[:, None, :]
            h = dr[0] * oc[0]
            h += dr[1] * oc[1]
            h += dr[2] * oc[2]
            oc -= h * dr  # now l, the centre's offset from the line
            oc *= oc
            distance2 = oc[0] + oc[1]
            distance2 += oc[2]
            reach2 = reach * reach
            candidate = distance2 <= reach2
            with np.errstate(invalid="ignore"):  # NaN beyond reach (no candidate anyway), or inf - inf
                far = np.sqrt(np.subtract(reach2, distance2, out=reach2), out=reach2)
            far += h
            # candidate and not (far < floor), one comparison of bools (True > False only);
            # not ">=": a NaN far root stays a candidate
            np.greater(candidate, far < ray_floor.take(ray, mode="wrap"), out=candidate)
            h -= reach
            candidate &= h <= to_beat.take(ray, mode="wrap")
            slot = candidate.ravel().nonzero()[0]  # j * P + pair for primitive j of pair's leaf
            j, pair = divmod_by(slot, ray.size)
            row = node.take(pair, mode="wrap") * self.leaf_size + j  # slot j of node k at k * leaf_size + j
            prim = self.leaf_primitive.take(row, mode="wrap")
            return slot, pair, prim

        def test_slots(ray, node):
            """Test (ray, leaf) pairs against their leaves' primitives.

            A float32 slab test in the traversal's frame of every (ray,
            primitive) slot against the primitive's own padded box keeps
            those the ray enters before ``to_beat``; padding slots are NaN
            and never kept.  Only the kept slots, typically a few in ten,
            are tested with brute force's arithmetic in the scene's
            precision.
            """
            part = max(1, LEAF_SLOTS // self.leaf_size)
            if ray.size > part:  # bounded temporaries (see LEAF_SLOTS): the same tests, in parts
                for a in range(0, ray.size, part):
                    test_slots(ray[a:a + part], node[a:a + part])
                return
            if self.sphere_leaves:
                slot, pair, prim = sphere_slots(ray, node)
            # np.minimum, not fmin, at the end of `leave`: a padding slot's NaN must survive to
            # fail the test (a real box is never NaN on all three axes: its planes differ on each)
            else:
                r = rays.take(ray, axis=1, mode="wrap")[:, None, :]
                shape = (2, 3, self.leaf_size, ray.size)  # lo/hi, axis, slot, pair
                b = gather_minus(self.leaf_boxes32, node, shape, r[:3])
                b *= r[3:]
                near, far = np.fmin(b[0], b[1]), np.fmax(b[0], b[1], out=b[1])
                entry, leave = _entry_leave(near, far, floors(ray.size), to_beat.take(ray, mode="wrap"), np.minimum)
                slot = (entry <= leave).ravel().nonzero()[0]  # j * P + pair for primitive j of pair's leaf
                j, pair = divmod_by(slot, ray.size)
                row = node.take(pair, mode="wrap") * self.leaf_size + j  # slot j of node k at k * leaf_size + j
                if self.leaf_planes32 is not None:
                    # the plane pass: keep the slots whose ray crosses (to within the margin)
                    # its triangle's plane between entering and leaving its box
                    plane = self.leaf_planes32.take(row, axis=0, mode="wrap")  # (S, 4): n / m, c / m
                    r = ray.take(pair, mode="wrap")
                    o32 = rays[:3].take(r, axis=1, mode="wrap")  # the origins only
                    dr = d32.take(r, axis=1, mode="wrap")
                    at_origin = plane[:, 0] * o32[0]
                    at_origin += plane[:, 1] * o32[1]
                    at_origin += plane[:, 2] * o32[2]
                    at_origin -= plane[:, 3]
                    along = plane[:, 0] * dr[0]
                    along += plane[:, 1] * dr[1]
                    along += plane[:, 2] * dr[2]
                    s0 = entry.ravel().take(slot, mode="wrap") * along
                    s0 += at_origin
                    s1 = leave.ravel().take(slot, mode="wrap") * along
                    s1 += at_origin
                    # NaN (no plane) compares false: kept
                    apart = (np.minimum(s0, s1) > 1) | (np.maximum(s0, s1) < -1)
                    near_plane = (~apart).nonzero()[0]
                    slot, pair = slot.take(near_plane, mode="wrap"), pair.take(near_plane, mode="wrap")
                    row = row.take(near_plane, mode="wrap")
                prim = self.leaf_primitive.take(row, mode="wrap")
            ray = ray.take(pair, mode="wrap")
            t = self.primitives.t_pairs(prim, gather(o, ray), gather(d, ray),
                                        None if time is None else time.take(ray, mode="wrap"))
            # (t < limit is false for a miss, inf or NaN, whatever the limit)
            ok = ((t < (limit_one if limit_one is not None else limit.take(ray, mode="wrap")))
                  & (t <= nearest.take(ray, mode="wrap"))).nonzero()[0]
            ray, t, prim = ray.take(ok, mode="wrap"), t.take(ok, mode="wrap"), prim.take(ok, mode="wrap")
            if any_hit:
                to_beat[ray] = -np.inf  # done: no box is entered before 0
            else:
                np.minimum.at(nearest, ray, t)
                bound = float32_up_nonnegative(nearest.take(ray, mode="wrap") - shift.take(ray, mode="wrap"))
                to_beat[ray] = bound if cap is None else np.fmin(bound, cap.take(ray, mode="wrap"), out=bound)
            found.append((ray, t, prim))

        # Every kind's exact test keeps only t > T_MIN, so a box the ray leaves before T_MIN
        # holds no hit: entries are clamped at T_MIN, in the traversal's frame, rather than at
        # 0, and such boxes fail entry <= leave.  One bound for the batch (the least of its
        # rays'), rounded down; it matters for rays leaving a surface (shift 0), which start
        # inside the boxes of the primitives around their origin: on the 1M terrain it drops
        # a tenth of their exact tests.
        # (float32_down, on a scalar; the least of ray_floor where there is one: float32_down is monotone)
        # Taken over every ray of the batch, those that miss the root box included: a floor at
        # most the walking rays' own (the others' shifts are >= 0, inf or NaN, which fmin and
        # fmax skip), so it drops no box they need; it is lower (0) only where the walking rays
        # all start within T_MIN of the root box and another starts outside.  (Masked to the
        # walking rays, the reduction took ~30 us a batch of 16,384, ~1.5 % of its traversal.)
        with np.errstate(invalid="ignore"):
            ray_floor = float32_floor(shift) if self.sphere_leaves else None
        floor = max(f32(0), np.fmin.reduce(ray_floor) if ray_floor is not None else
                    np.nextafter(f32(T_MIN - np.fmax.reduce(shift)), f32(-np.inf)))
        # ... as a row of pairs: NumPy's fmax loop is vectorised for two arrays, not for an
        # array and a scalar (4 x 12,000 float32 in place: 8 against 40 us), so the walk's
        # clamp of its entries at the floor takes a slice of this row, grown as needed (the
        # same numbers; the cover's recorded calls: ~2.4 -> ~0.6 ns a pair, ~3 % of a step)
        floor_row = [np.empty(0, dtype=f32)]

        def floors(pairs):
            """``floor`` repeated ``pairs`` times."""
            if floor_row[0].size < pairs:
                floor_row[0] = np.full(max(pairs, 2 * floor_row[0].size), floor, dtype=f32)
            return floor_row[0][:pairs]
        # ... and each ray's own, for the sphere pass (see sphere_slots), where one gather serves
        # a whole (leaf_size, P) pass: a bounce ray's exact test of the ball it leaves is
        # dropped only where T_MIN is its floor, while the batch's is 0 as soon as one of its
        # rays comes from outside the tree (made above)
        if self.node_major:
            def gather_columns(table, node):
                """``table``'s rows ``node`` as columns: (R, P) from a node-major (K, R) table."""
                # one gather of whole rows (a cache line or three each: one column per row
                # was a cache miss per element), then one transposed copy, so all the
                # arithmetic after it runs on contiguous pair-minor rows with each ray's
                # numbers broadcast along them: on the gathered (P, R) rows themselves the
                # reductions over planes ran strided, 1 ns an element against 0.13
                rows = table.take(node, axis=0, mode="wrap")
                columns = np.empty(rows.shape[::-1], dtype=rows.dtype)
                np.copyto(columns, rows.T)
                return columns

            def gather_minus(table, node, shape, minus):
                """``gather_columns(table, node).reshape(shape) - minus``, with the transposed
                copy done by the subtraction itself (one pass over the gathered rows instead
                of two: the leaf pass ~15 % faster)."""
                rows = table.take(node, axis=0, mode="wrap")
                return np.subtract(rows.T.reshape(shape), minus, out=np.empty(shape, dtype=rows.dtype))
        else:
            def gather_columns(table, node):
                """``table``'s columns ``node``: (R, P) from a (R, K) table."""
                return table.take(node, axis=1, mode="wrap")

            def gather_minus(table, node, shape, minus):
                """``gather_columns(table, node).reshape(shape) - minus``."""
                columns = gather_columns(table, node).reshape(shape)
                columns -= minus
                return columns
        ray = ray_ids
        if self.count[0] > 0:  # the whole tree is one leaf, and these rays entered its box
            test_slots(ray, np.zeros(ray.size, dtype=np.int64))
            ray = ray[:0]
        # the root's column in each ray's octant (none if the root was a leaf): the octant
        # 4 sz + 2 sy + sx from the sign bits in uint8, one multiply to int64 (three ors of
        # bools shifted to int64 took ~17 us of a batch's 7,000 rays, this ~9)
        if self.octants > 1:
            sign = np.signbit(d).view(np.uint8)
            octant = sign[2] * np.uint8(4)
            octant += sign[1] * np.uint8(2)
            octant += sign[0]
            node = np.multiply(octant if ray.size == octant.size else octant.take(ray, mode="wrap"), k, dtype=np.int64)
        else:
            node = np.zeros(ray.size, dtype=np.int64)

        def walk(ray, node, depth, stop=None, rays_walking=ray_ids.size):
            """Breadth-first over (ray, interior node) pairs at ``depth``, testing leaves as
            they are reached; with ``stop``, returns the (ray, interior node, entry) pairs
            of that depth instead of walking them further."""
            # both children's boxes are tested at once so each level gathers the ray data once
            last = self.first_leaf_depth if stop is None else min(stop, self.first_leaf_depth)
            while ray.size:
                if ray.size > WALK_PAIRS:  # bounded memory (see WALK_PAIRS): walk the level in parts
                    parts = [walk(ray[a:a + WALK_PART], node[a:a + WALK_PART], depth, stop, rays_walking)
                             for a in range(0, ray.size, WALK_PART)]
                    parts = [p for p in parts if p is not None]
                    return tuple(np.concatenate(x) for x in zip(*parts)) if parts else None
                pairs = ray.size
                levels = max(1, min(STEP_LEVELS, last - depth)) if self.node_major else \
                    max(1, min((last - depth) % SMALL_STEP_LEVELS or SMALL_STEP_LEVELS, last - depth))
                # mode="wrap" skips the bounds check (indices are valid by construction); measured 30 % faster
                r = walk_rays.take(ray, axis=1, mode="wrap")
                top = self.top_boxes.get(levels)
                shape = (2, axes, 1 << levels, pairs)  # enter/leave (lo/hi), axis, child (descendant), pair
                if top is not None and (2 << depth) - 1 <= top.shape[1]:  # every node of the depth is in it
                    t = top.take(node, axis=1, mode="wrap").reshape(shape)
                    t -= r[:axes, None]
                else:
                    t = gather_minus(self.octant_boxes if levels == 1 else self.descendant_boxes[levels]
                                     if self.node_major else self.octant_descendants[levels], node, shape, r[:axes, None])
                t *= r[axes:, None]
                if self.octants == 1:  # lo/hi planes: the nearer of each pair is where the ray enters
                    near, far = np.fmin(t[0], t[1]), np.fmax(t[0], t[1], out=t[1])
                else:
                    near, far = t[0], t[1]
                entry, leave = _entry_leave(near, far, floors(pairs), to_beat.take(ray, mode="wrap"), np.fmin)
                keep = (entry <= leave).ravel().nonzero()[0]  # <=: keep ties; left children first, then right
                # a kept index k is child k // pairs of pair k % pairs: "wrap" does the modulo
                node = node.take(keep, mode="wrap")
                ray = ray.take(keep, mode="wrap")
                if levels > 1 and not self.node_major:
                    # a step onto the leaves of a complete tree gives their node numbers (what
                    # test_leaves reads: no column -> node division), others columns
                    onto_leaves = self.complete and depth + levels == self.first_leaf_depth
                    node = (self.leaf_below if onto_leaves else self.octant_below)[levels].take(node, mode="wrap")
                    node += keep // pairs
                    depth += levels - 1
                elif levels > 1:
                    node <<= levels
                    node += keep // pairs + ((1 << levels) - 1)
                    depth += levels - 1  # and one more below
                elif depth < self.first_leaf_depth and self.node_major:
                    # above the first leaves every level is full, so node n's children are
                    # 2n + 1 and 2n + 2: arithmetic instead of a gather from a table of K
                    # (a cache miss a pair in big trees; small trees' table is in cache,
                    # and gathering from it measured 2 % faster on W2 than the arithmetic)
                    node *= 2
                    node += keep >= pairs
                    node += 1
                else:
                    node = self.octant_left.take(node, mode="wrap") + (keep >= pairs)
                depth += 1
                if depth < self.first_leaf_depth:
                    inner = None
                elif depth == self.first_leaf_depth and self.complete:  # every pair is a leaf's
                    test_leaves(ray, node if self.octants == 1 or levels > 1 else divmod_by(node, k)[1],
                                entry.ravel(), keep, rays_walking)
                    ray = node = inner = ray[:0]
                else:
                    is_leaf = self.octant_is_leaf.take(node, mode="wrap")
                    leaf = is_leaf.nonzero()[0]
                    inner = None
                    if leaf.size:
                        leaf_node = node.take(leaf, mode="wrap")
                        if self.octants > 1:
                            leaf_node = divmod_by(leaf_node, k)[1]  # column -> node
                        test_leaves(ray.take(leaf, mode="wrap"), leaf_node, entry.ravel(), keep.take(leaf, mode="wrap"),
                                    rays_walking)
                        inner = (~is_leaf).nonzero()[0]
                        ray, node = ray.take(inner, mode="wrap"), node.take(inner, mode="wrap")
                if depth == stop:
                    entry = entry.ravel().take(keep, mode="wrap")
                    return ray, node, entry if inner is None else entry.take(inner, mode="wrap")
            return None

        if self.subtree_depth is None or self.subtree_depth <= 0:
            walk(ray, node, 0)
        else:
            # Subtree rounds: walk down to subtree_depth, then walk each ray's nearest
            # subtrees first (ties included) and drop the subtrees it enters beyond its best
            # hit so far, as test_leaves does for leaves.  Breadth-first, a ray that hits the
            # terrain nearby still walks every box along its whole line down to the leaves.
            found_pairs = walk(ray, node, 0, self.subtree_depth)
            if found_pairs is not None:
                ray, node, entry = found_pairs
                for round_ in range(SUBTREE_ROUNDS):
                    if not ray.size:
                        break
                    if round_ == SUBTREE_ROUNDS - 1:
                        walk(ray, node, self.subtree_depth)
                        break
                    first = np.full(origin.shape[1], np.inf, dtype=f32)
                    np.minimum.at(first, ray, entry)
                    now = entry <= first.take(ray, mode="wrap")
                    walk(ray[now], node[now], self.subtree_depth, rays_walking=np.count_nonzero(first < np.inf))
                    later = (~now).nonzero()[0]
                    ray, node = ray.take(later, mode="wrap"), node.take(later, mode="wrap")
                    entry = entry.take(later, mode="wrap")
                    alive = (entry <= to_beat.take(ray, mode="wrap")).nonzero()[0]
                    ray, node = ray.take(alive, mode="wrap"), node.take(alive, mode="wrap")
                    entry = entry.take(alive, mode="wrap")
        # walk and test_slots call themselves (parts, for bounded memory), so each closure holds
        # a reference to itself: a cycle that kept every array of the call (rays, bounds, pair
        # lists) alive until the garbage collector's next pass, and W2 rendered ~10 % slower
        # (more memory touched, and the collector's passes).  Unset, they are freed on return.
        walk = test_slots = None  # noqa: F841
        return found
