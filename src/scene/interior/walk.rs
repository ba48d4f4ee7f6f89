//! The walk over places: a graph joining places of neighbouring cells that a person could step
//! between (a step height for stairs and ramps, clearance at the eye and the knees for doorways),
//! its largest connected part, waypoints spread over it (open places far apart along the
//! graph) and a tour through them along shortest paths.

use std::collections::{BinaryHeap, HashMap};

use glam::Vec3;

use super::places::{Place, Scale};
use super::rays::TriangleScene;
use crate::scene::camera::FRAMES_PER_KEY;
use crate::scene::path_check::{one_colour_and_back_at, one_colour_at, VIEW_RAYS};
use crate::scene::CameraPose;

/// Neighbour lists: places in adjacent cells (8-neighbourhood) whose floors differ by at most
/// a step, joined at eye height by a segment that keeps the margin and at knee height (a step
/// and a margin over the floors) by one that keeps half of it.
pub fn neighbours(rays: &TriangleScene, places: &[Place], s: &Scale) -> Vec<Vec<usize>> {
    let mut by_cell: HashMap<(i32, i32), Vec<usize>> = HashMap::new();
    for (i, p) in places.iter().enumerate() {
        by_cell.entry(p.cell).or_default().push(i);
    }
    let knee = Vec3::Y * (s.step + s.margin);
    let mut adj = vec![Vec::new(); places.len()];
    for (i, p) in places.iter().enumerate() {
        for dz in -1..=1 {
            for dx in -1..=1 {
                // Each pair once: the later cell links back.
                if (dz, dx) <= (0, 0) {
                    continue;
                }
                let Some(js) = by_cell.get(&(p.cell.0 + dx, p.cell.1 + dz)) else {
                    continue;
                };
                for &j in js {
                    let q = &places[j];
                    if (q.floor.y - p.floor.y).abs() <= s.step
                        && rays.segment_clear(p.eye, q.eye, s.margin)
                        && rays.segment_clear(p.floor + knee, q.floor + knee, 0.5 * s.margin)
                    {
                        adj[i].push(j);
                        adj[j].push(i);
                    }
                }
            }
        }
    }
    adj
}

/// The places of the largest connected part of the graph (ties: the one found first).
pub fn largest_component(adj: &[Vec<usize>]) -> Vec<usize> {
    let mut seen = vec![false; adj.len()];
    let mut best: Vec<usize> = Vec::new();
    for start in 0..adj.len() {
        if seen[start] {
            continue;
        }
        let part = flood(adj, start, &mut seen, |_, _| true);
        if part.len() > best.len() {
            best = part;
        }
    }
    best
}

/// The places reached from `start` (not yet `seen`) over the edges `join(i, j)` accepts,
/// breadth first; marks them seen.
fn flood(
    adj: &[Vec<usize>],
    start: usize,
    seen: &mut [bool],
    join: impl Fn(usize, usize) -> bool,
) -> Vec<usize> {
    seen[start] = true;
    let mut part = vec![start];
    let mut k = 0;
    while k < part.len() {
        let i = part[k];
        for &j in &adj[i] {
            if !seen[j] && join(i, j) {
                seen[j] = true;
                part.push(j);
            }
        }
        k += 1;
    }
    part
}

/// Most floor height between neighbouring cells of one flat area, in eye heights: a slope or
/// an uneven floor, not a stair's riser or a bed.
pub const FLAT_RISE: f32 = 0.1;
/// What a unit of height climbed or descended beyond [`FLAT_RISE`] costs on the tour's legs,
/// in units walked: a route steps around a bed or a table rather than over it, and still
/// takes the stairs.
pub const CLIMB_COST: f32 = 4.0;
/// Least area of a flat floor that stands above all around it for it to be walked to, in
/// square eye heights: a bed's or a table's top is smaller than a room's floor.
pub const MIN_FLAT_AREA: f32 = 2.0;

/// Shortest paths from `sources` (cost: length, more near walls through the openness, and
/// `climb_cost` per unit of height climbed or descended at a step), returning each place's
/// predecessor and distance.
pub fn dijkstra(
    places: &[Place],
    adj: &[Vec<usize>],
    sources: &[usize],
    eye_height: f32,
    climb_cost: f32,
) -> (Vec<usize>, Vec<f32>) {
    #[derive(PartialEq)]
    struct Item(f32, usize);
    impl Eq for Item {}
    impl PartialOrd for Item {
        fn partial_cmp(&self, o: &Self) -> Option<std::cmp::Ordering> {
            Some(self.cmp(o))
        }
    }
    impl Ord for Item {
        fn cmp(&self, o: &Self) -> std::cmp::Ordering {
            o.0.total_cmp(&self.0).then(o.1.cmp(&self.1))
        }
    }
    let mut dist = vec![f32::INFINITY; places.len()];
    let mut prev = vec![usize::MAX; places.len()];
    let mut heap = BinaryHeap::new();
    for &s in sources {
        dist[s] = 0.0;
        heap.push(Item(0.0, s));
    }
    while let Some(Item(d, i)) = heap.pop() {
        if d > dist[i] {
            continue;
        }
        for &j in &adj[i] {
            let len = places[i].eye.distance(places[j].eye);
            let rise = (places[j].floor.y - places[i].floor.y).abs();
            let climb = climb_cost * (rise - FLAT_RISE * eye_height).max(0.0);
            let nd =
                d + len * (1.0 + eye_height / places[j].openness.max(1e-3 * eye_height)) + climb;
            if nd < dist[j] {
                dist[j] = nd;
                prev[j] = i;
                heap.push(Item(nd, j));
            }
        }
    }
    (prev, dist)
}

/// Waypoints over `part`: its most open place, then repeatedly the open place farthest along
/// the graph from those chosen, up to `count`. Open: openness at least the median of the
/// places on a floor (not on furniture: [`on_furniture`]), and a wall
/// no nearer than an eye height where there are `count` such (a furnished house's rooms may
/// hold one or none).
pub fn waypoints(
    places: &[Place],
    adj: &[Vec<usize>],
    part: &[usize],
    count: usize,
    s: &Scale,
) -> Vec<usize> {
    let eye_height = s.eye_height;
    let furniture = on_furniture(places, adj, s);
    let on_floor: Vec<usize> = part.iter().copied().filter(|&i| !furniture[i]).collect();
    let part = if on_floor.is_empty() {
        part
    } else {
        &on_floor[..]
    };
    let mut open: Vec<f32> = part.iter().map(|&i| places[i].openness).collect();
    open.sort_by(f32::total_cmp);
    let median = open.get(open.len() / 2).copied().unwrap_or(0.0);
    let open: Vec<usize> = part
        .iter()
        .copied()
        .filter(|&i| places[i].openness >= median)
        .collect();
    let roomy: Vec<usize> = open
        .iter()
        .copied()
        .filter(|&i| places[i].nearest >= eye_height)
        .collect();
    let candidates = if roomy.len() < count.max(2) {
        open
    } else {
        roomy
    };
    let Some(&start) = candidates.iter().max_by(|&&a, &&b| {
        places[a]
            .openness
            .total_cmp(&places[b].openness)
            .then(b.cmp(&a))
    }) else {
        return Vec::new();
    };
    let mut chosen = vec![start];
    while chosen.len() < count.max(2) {
        let (_, dist) = dijkstra(places, adj, &chosen, eye_height, 0.0);
        let far = candidates
            .iter()
            .copied()
            .filter(|&i| dist[i].is_finite() && dist[i] > 0.0)
            .max_by(|&a, &b| dist[a].total_cmp(&dist[b]).then(b.cmp(&a)));
        match far {
            Some(i) => chosen.push(i),
            None => break,
        }
    }
    chosen
}

/// Places on the top of a piece of furniture: a flat area (neighbours at most [`FLAT_RISE`]
/// apart) smaller than [`MIN_FLAT_AREA`] with neighbours outside it, all lower: a bed's or a
/// table's top, not a stair's tread (a higher tread follows) or a room's floor.
pub fn on_furniture(places: &[Place], adj: &[Vec<usize>], s: &Scale) -> Vec<bool> {
    let level = FLAT_RISE * s.eye_height;
    let least = MIN_FLAT_AREA * s.eye_height * s.eye_height;
    let mut top = vec![false; places.len()];
    let mut seen = vec![false; places.len()];
    let rise = |i: usize, j: usize| places[j].floor.y - places[i].floor.y;
    for start in 0..places.len() {
        if seen[start] {
            continue;
        }
        let patch = flood(adj, start, &mut seen, |i, j| rise(i, j).abs() <= level);
        let (mut higher_around, mut lower_around) = (false, false);
        for &i in &patch {
            for &j in &adj[i] {
                let r = rise(i, j);
                if r.abs() > level {
                    higher_around |= r > 0.0;
                    lower_around |= r < 0.0;
                }
            }
        }
        let small = (patch.len() as f32) * s.cell * s.cell < least;
        if small && lower_around && !higher_around {
            for &i in &patch {
                top[i] = true;
            }
        }
    }
    top
}

/// The tour's place indices: from the first waypoint, greedily the nearest (by path) of the
/// others, joined by shortest paths.
pub fn tour(places: &[Place], adj: &[Vec<usize>], chosen: &[usize], eye_height: f32) -> Vec<usize> {
    let Some(&start) = chosen.first() else {
        return Vec::new();
    };
    let mut route = vec![start];
    let mut current = start;
    let mut left: Vec<usize> = chosen[1..].to_vec();
    while !left.is_empty() {
        let (prev, dist) = dijkstra(places, adj, &[current], eye_height, CLIMB_COST);
        let k = (0..left.len())
            .min_by(|&a, &b| dist[left[a]].total_cmp(&dist[left[b]]))
            .unwrap_or(0);
        let goal = left.remove(k);
        if !dist[goal].is_finite() {
            continue;
        }
        let mut leg = vec![goal];
        while let Some(&p) = leg.last().map(|&l| &prev[l]) {
            if p == usize::MAX || p == current {
                break;
            }
            leg.push(p);
        }
        leg.reverse();
        route.extend(leg);
        current = goal;
    }
    route
}

/// Keys along `eyes` about every `2.5` cells (at least 0.8 eye heights), each looking the most
/// open way ahead (see [`look_dirs`]) at a target `TARGET_REACH` eye heights away; when the
/// spline through them would come closer than the margin to geometry, every eye is a key.
/// Where the turn between two keys sweeps across a view of more than `one_colour_most` of one
/// colour, one key takes the other's direction (`hold_views`); then the views are judged every
/// few frames and a turn that still shows more than `one_colour_most` + 0.08 of one colour
/// gets other looks at its keys (`mend_turns`).
pub fn keys_through(
    rays: &TriangleScene,
    eyes: &[Vec3],
    s: &Scale,
    one_colour_most: f32,
) -> Vec<CameraPose> {
    let spacing = (2.5 * s.cell).max(0.8 * s.eye_height);
    let reach = TARGET_REACH * s.eye_height;
    let mut keys: Vec<Vec3> = Vec::new();
    for &e in eyes {
        if keys.last().is_none_or(|l| l.distance(e) >= spacing) {
            keys.push(e);
        }
    }
    if let (Some(&last), Some(&k)) = (eyes.last(), keys.last()) {
        if k != last {
            keys.push(last);
        }
    }
    // The spline of the eyes does not depend on where they look.
    let mut path = crate::scene::CameraPath {
        name: String::new(),
        keys: keys
            .iter()
            .map(|&eye| CameraPose {
                eye,
                target: eye + Vec3::NEG_Z,
            })
            .collect(),
    };
    let frames = path.natural_frames();
    let clear = (0..=frames).all(|f| !rays.within(path.pose_at(f as f32).eye, s.margin));
    let eyes = if clear { &keys[..] } else { eyes };
    path.keys = poses_of(rays, eyes, s.eye_height, reach, one_colour_most);
    let views = Views::new(rays);
    hold_views(&views, &mut path, one_colour_most);
    mend_turns(&views, &mut path, one_colour_most + MEND_SLACK);
    path.keys
}

/// The views [`hold_views`] and [`mend_turns`] judge, each judged once: both judge the same
/// views again and again (the views around a key before and after each look it tries, every
/// segment's worst view in every pass), and a view's judgement depends only on its pose and
/// grid.
struct Views<'a> {
    rays: &'a TriangleScene,
    /// Per pose (eye and target, bit for bit) and grid: the share of one colour and of back
    /// faces.
    judged: std::sync::Mutex<HashMap<ViewKey, (f32, f32)>>,
}

/// A view's pose (eye and target as bits) and grid.
type ViewKey = ([u32; 6], (usize, usize));

impl<'a> Views<'a> {
    fn new(rays: &'a TriangleScene) -> Views<'a> {
        Views {
            rays,
            judged: Default::default(),
        }
    }

    /// [`one_colour_and_back_at`] of `pose` through a grid of `grid` rays.
    fn one_colour_and_back(&self, pose: &CameraPose, grid: (usize, usize)) -> (f32, f32) {
        let (e, t) = (pose.eye.to_array(), pose.target.to_array());
        let key = ([e[0], e[1], e[2], t[0], t[1], t[2]].map(f32::to_bits), grid);
        let lock = || self.judged.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(&v) = lock().get(&key) {
            return v;
        }
        // Judged outside the lock (another thread may judge the same view meanwhile: the same
        // value).
        let v = one_colour_and_back_at(self.rays, pose, grid);
        lock().insert(key, v);
        v
    }
}

/// Most share of one colour of the views between two keys (a third and two thirds of the way).
fn between(views: &Views, path: &crate::scene::CameraPath, segment: usize) -> f32 {
    most_one_colour(views, &between_poses(path, segment))
}

/// The two views of [`between`].
fn between_poses(path: &crate::scene::CameraPath, segment: usize) -> [CameraPose; 2] {
    [1.0, 2.0].map(|j| path.pose_at((segment as f32 + j / 3.0) * FRAMES_PER_KEY))
}

/// Most share of one colour of the views at `poses`, judged on the machine's cores.
fn most_one_colour(views: &Views, poses: &[CameraPose]) -> f32 {
    crate::parallel::map(poses.len(), |i| {
        views.one_colour_and_back(&poses[i], VIEW_RAYS).0
    })
    .into_iter()
    .fold(0.0, f32::max)
}

/// Where turning from one key's view to the next sweeps across a wall or a bare floor (a view
/// between them has more than `most` of one colour), one of the two keys takes the other's
/// look direction when that makes the worst view around them better; `HOLD_ROUNDS` passes
/// along the path.
fn hold_views(views: &Views, path: &mut crate::scene::CameraPath, most: f32) {
    let n = path.keys.len();
    let around = |path: &crate::scene::CameraPath, k: usize| {
        let poses: Vec<CameraPose> = (k.saturating_sub(2)..(k + 3).min(n - 1))
            .flat_map(|s| between_poses(path, s))
            .chain((k.saturating_sub(1)..(k + 3).min(n)).map(|j| path.keys[j]))
            .collect();
        most_one_colour(views, &poses)
    };
    for _ in 0..HOLD_ROUNDS {
        let mut changed = false;
        for k in 0..n.saturating_sub(1) {
            if between(views, path, k) <= most {
                continue;
            }
            let before = around(path, k);
            for (from, to) in [(k, k + 1), (k + 1, k)] {
                let old = path.keys[to];
                let look = path.keys[from].target - path.keys[from].eye;
                path.keys[to].target = old.eye + look;
                if around(path, k) < before {
                    changed = true;
                    break;
                }
                path.keys[to] = old;
            }
        }
        if !changed {
            break;
        }
    }
}

/// Frames between the views judged along a turn by [`mend_turns`]: a wall that fills the view
/// while the camera sweeps past it does so for about ten frames.
const MEND_STEP: u32 = 3;
/// Coarser step and ray grid on which [`mend_turns`] ranks its candidate looks before judging
/// the best few at `MEND_STEP` on [`COLOUR_RAYS`].
const MEND_RANK: (u32, (usize, usize)) = (6, (10, 6));
/// Weight of a view's share of back faces against its share of one colour in [`mend_turns`].
const BACK_WEIGHT: f32 = 8.0;
/// Candidate looks judged in full per segment mended.
const MEND_FINALISTS: usize = 6;
/// Candidates of [`mend_segment`] ranked in full before the others are cut short.
const MEND_FULLY_RANKED: usize = 4 * MEND_FINALISTS;

/// The views of segment `segment` (from its key's frame to the next key's, every `step` frames,
/// both keys included) through a grid of `grid` rays, each judged by its share of one colour,
/// or `BACK_WEIGHT` times its share of back faces when that is more (a view into a solid is
/// as bad as a wall close ahead when a twentieth of it shows back faces).
fn segment_views<'a>(
    views: &'a Views,
    path: &'a crate::scene::CameraPath,
    segment: usize,
    (step, grid): (u32, (usize, usize)),
) -> impl Iterator<Item = f32> + 'a {
    let first = segment as f32 * FRAMES_PER_KEY;
    let frames = FRAMES_PER_KEY as u32;
    (0..frames)
        .step_by(step as usize)
        .chain(std::iter::once(frames))
        .map(move |j| {
            let (one, back) = views.one_colour_and_back(&path.pose_at(first + j as f32), grid);
            one.max(BACK_WEIGHT * back)
        })
}

/// The worst view of segment `segment` (see [`segment_views`]).
fn segment_worst(
    views: &Views,
    path: &crate::scene::CameraPath,
    segment: usize,
    judge: (u32, (usize, usize)),
) -> f32 {
    segment_views(views, path, segment, judge).fold(0.0, f32::max)
}

/// How far the views of `segments` go over `above`: the sum of each view's excess squared, so
/// that a look is judged by how many views it spoils and by how much. Summing stops as soon as
/// the sum passes `cap` (`f32::INFINITY`: never): the value is exact wherever it is at most
/// `cap`, else a partial sum over `cap` (the views are added in the same order either way).
fn excess(
    views: &Views,
    path: &crate::scene::CameraPath,
    segments: std::ops::Range<usize>,
    judge: (u32, (usize, usize)),
    above: f32,
    cap: f32,
) -> f32 {
    // The empty sum of `Iterator::sum`, so that every sum is the one it would give.
    let mut sum: f32 = std::iter::empty::<f32>().sum();
    for v in segments.flat_map(|s| segment_views(views, path, s, judge)) {
        sum += (v - above).max(0.0).powi(2);
        if sum > cap {
            break;
        }
    }
    sum
}

/// How much more of one colour than a key's look aims at (`one_colour_most`) a view between
/// keys may show before [`mend_turns`] mends its segment: 0.38 with the default 0.3, as a
/// frame of over 40% one colour shows little of the level and the estimate on [`COLOUR_RAYS`]
/// is within about 0.02 of the rendered image's share.
const MEND_SLACK: f32 = 0.08;

/// [`excess`] over the segments that keys `keys` shape (a Catmull-Rom spline: the two
/// before a key and the two after).
fn excess_around(
    views: &Views,
    path: &crate::scene::CameraPath,
    keys: std::ops::RangeInclusive<usize>,
    judge: (u32, (usize, usize)),
    above: f32,
    cap: f32,
) -> f32 {
    let segments = path.keys.len() - 1;
    let shaped = keys.start().saturating_sub(2)..(keys.end() + 2).min(segments);
    excess(views, path, shaped, judge, above, cap)
}

/// Where a view between two keys, judged every `MEND_STEP` frames, has more than
/// `above` of one colour (the camera sweeps past a close wall while it turns), one of
/// the two keys or both take another look: one of the `LOOK_DIRS` level directions at one of
/// the `LOOK_DOWN_DEG` angles (both keys the same: the camera does not turn on that segment),
/// or a neighbour's look. Candidates are ranked on the segment and its two neighbours with a
/// coarse grid; the best few are judged on every segment the keys shape (`excess_around`), and
/// the best is kept when it is better than the keys' own looks.
fn mend_turns(views: &Views, path: &mut crate::scene::CameraPath, above: f32) {
    let n = path.keys.len();
    if n < 2 {
        return;
    }
    let judge = (MEND_STEP, COLOUR_RAYS);
    // Per segment: when a key that shapes it last changed, and when it was last tried.
    let mut changed_at = vec![1usize; n - 1];
    let mut tried_at = vec![0usize; n - 1];
    let mut clock = 1;
    for _ in 0..MEND_PASSES {
        let worst = crate::parallel::map(n - 1, |k| segment_worst(views, path, k, judge));
        for (k, &w) in worst.iter().enumerate() {
            // Skipped when tried since its keys last changed, or mended by a neighbour's key.
            if w <= above
                || tried_at[k] > changed_at[k]
                || segment_worst(views, path, k, judge) <= above
            {
                continue;
            }
            clock += 1;
            tried_at[k] = clock;
            if let Some((a, b)) = mend_segment(views, path, k, above) {
                clock += 1;
                let shaped = a.saturating_sub(2)..(b + 2).min(n - 1);
                changed_at[shaped].fill(clock);
            }
        }
    }
}

/// Passes of [`mend_turns`] along a path (a mended turn may move to the segment before); a
/// segment is tried again only when one of its keys changed since.
const MEND_PASSES: usize = 2;

/// One segment of [`mend_turns`]: the keys that took another look, if any.
fn mend_segment(
    views: &Views,
    path: &mut crate::scene::CameraPath,
    k: usize,
    above: f32,
) -> Option<(usize, usize)> {
    let n = path.keys.len();
    let judge = (MEND_STEP, COLOUR_RAYS);
    // (first key, last key, unit look) of the keys that take the look
    let mut candidates: Vec<(usize, usize, Vec3)> = Vec::new();
    for d in 0..LOOK_DIRS {
        for deg in LOOK_DOWN_DEG {
            let look = Look {
                dir: level_dir(d),
                down: deg.to_radians().tan(),
            }
            .unit();
            for keys in [(k, k), (k + 1, k + 1), (k, k + 1)] {
                candidates.push((keys.0, keys.1, look));
            }
        }
    }
    for key in [k, k + 1] {
        for other in key.saturating_sub(1)..(key + 2).min(n) {
            if other != key {
                let look = path.keys[other].target - path.keys[other].eye;
                candidates.push((key, key, look.normalize_or(Vec3::NEG_Z)));
            }
        }
    }
    let with = |c: usize| {
        let (a, b, look) = candidates[c];
        let mut trial = path.clone();
        for key in &mut trial.keys[a..=b] {
            key.target = key.eye + look * (key.target - key.eye).length();
        }
        trial
    };
    // Ranked on the segments next to the turn, where a look changes the views most.
    let near = k.saturating_sub(1)..(k + 2).min(n - 1);
    // Some candidates, spread over the list, are summed in full; the others stop once past
    // the `MEND_FINALISTS`-th best of those, as they can no longer be finalists: the finalists
    // and their order are those of full sums for every candidate.
    let stride = (candidates.len() / MEND_FULLY_RANKED).max(1);
    let full: Vec<usize> = (0..candidates.len()).step_by(stride).collect();
    let summed = crate::parallel::map(full.len(), |i| {
        excess(
            views,
            &with(full[i]),
            near.clone(),
            MEND_RANK,
            above,
            f32::INFINITY,
        )
    });
    let cap = {
        let mut best = summed.clone();
        best.sort_by(f32::total_cmp);
        best.get(MEND_FINALISTS - 1)
            .copied()
            .unwrap_or(f32::INFINITY)
    };
    let rest: Vec<usize> = (0..candidates.len()).filter(|c| c % stride != 0).collect();
    let capped = crate::parallel::map(rest.len(), |i| {
        excess(views, &with(rest[i]), near.clone(), MEND_RANK, above, cap)
    });
    let mut ranked = vec![0.0; candidates.len()];
    for (&c, &v) in full.iter().zip(&summed).chain(rest.iter().zip(&capped)) {
        ranked[c] = v;
    }
    let mut order: Vec<usize> = (0..candidates.len()).collect();
    order.sort_by(|&a, &b| ranked[a].total_cmp(&ranked[b]));
    order.truncate(MEND_FINALISTS);
    let sets = [(k, k), (k + 1, k + 1), (k, k + 1)];
    let before = crate::parallel::map(sets.len(), |i| {
        excess_around(
            views,
            path,
            sets[i].0..=sets[i].1,
            judge,
            above,
            f32::INFINITY,
        )
    });
    let judged = crate::parallel::map(order.len(), |i| {
        let (a, b, _) = candidates[order[i]];
        let was = sets
            .iter()
            .position(|&s| s == (a, b))
            .map_or(0.0, |j| before[j]);
        // Only a look under the keys' own excess is taken: summing stops past it.
        (
            was,
            excess_around(views, &with(order[i]), a..=b, judge, above, was),
        )
    });
    let best = (0..order.len())
        .filter(|&i| judged[i].1 < judged[i].0)
        .min_by(|&a, &b| judged[a].1.total_cmp(&judged[b].1));
    let best = order[best?];
    *path = with(best);
    Some((candidates[best].0, candidates[best].1))
}

/// Passes of [`hold_views`] along a path.
const HOLD_ROUNDS: usize = 3;

/// Distance of a key's target from its eye, in eye heights: far enough that interpolating the
/// targets of two keys turns the view steadily from one's direction to the other's.
const TARGET_REACH: f32 = 8.0;

/// Level look directions tried at each key.
const LOOK_DIRS: usize = 24;
/// Half angle of the fan of rays that measures how open one look direction is.
const LOOK_FAN_DEG: f32 = 8.0;
/// Openness counted at most, in eye heights: farther views are all equally good.
const LOOK_CAP: f32 = 25.0;
/// Weight of the look directions behind the way ahead (1 ahead, ½ sideways).
const LOOK_BACK: f32 = 0.3;
/// How far below level the walk looks, preferred first: a person walking looks a little down,
/// and the view then shows the floor ahead rather than a wall above it (or sky over a roofless
/// level); nearly level where the floor would fill the view in one colour.
const LOOK_DOWN_DEG: [f32; 3] = [10.0, 4.0, -2.0];
/// Most open look directions of a key whose views are judged by their colours.
const COLOUR_CANDIDATES: usize = 12;
/// Rays across and down a candidate view when judging its colours.
const COLOUR_RAYS: (usize, usize) = (24, 14);

/// A key's view: a level direction and how far below level it looks (the tangent).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Look {
    /// Unit level direction.
    pub dir: Vec3,
    /// Tangent of the angle below level.
    pub down: f32,
}

impl Look {
    /// The unit view direction.
    fn unit(&self) -> Vec3 {
        (self.dir + Vec3::NEG_Y * self.down).normalize()
    }

    fn at(&self, eye: Vec3, reach: f32) -> CameraPose {
        CameraPose {
            eye,
            target: eye + self.unit() * reach,
        }
    }
}

/// The `k`-th of the `LOOK_DIRS` level directions, evenly spaced around the vertical.
fn level_dir(k: usize) -> Vec3 {
    let a = std::f32::consts::TAU * k as f32 / LOOK_DIRS as f32;
    Vec3::new(a.cos(), 0.0, a.sin())
}

/// Views at `eyes`: at each, the level directions are ranked by how far their fan of three
/// rays sees front faces (a ray that escapes or hits a back face counts as nothing; openness
/// capped at `LOOK_CAP` eye heights), weighted from 1 straight along the way ahead to ½
/// sideways and `LOOK_BACK` behind; of the most open ones, the first whose view (looking
/// `LOOK_DOWN_DEG` down, the first angle preferred) has at most `most` of one colour (see
/// [`Probe::one_colour`](super::Probe)) is taken, else the one with the least: an untextured
/// floor or a wall close ahead filling the image shows nothing of the level. Then smoothed
/// with the neighbours' so the view turns gradually (unless the smoothed view has more of one
/// colour than `most` and than its own). Looks down rooms and corridors rather than at a close
/// wall or a bare floor, turning round when the way ahead ends at one.
pub fn look_dirs(rays: &TriangleScene, eyes: &[Vec3], eye_height: f32, most: f32) -> Vec<Look> {
    let n = eyes.len();
    let far = rays.bounds.extent().length() * 2.0 + 1.0;
    let cap = LOOK_CAP * eye_height;
    let reach = |eye: Vec3, d: Vec3| match rays.hit(eye, d, far) {
        Some(h) if h.front => h.t.min(cap),
        _ => 0.0,
    };
    let one_colour = |eye: Vec3, look: Look| one_colour_at(rays, &look.at(eye, 1.0), COLOUR_RAYS);
    let raw: Vec<(f32, Look)> = crate::parallel::map(n, |i| {
        let ahead = eyes[(i + 2).min(n - 1)] - eyes[i.saturating_sub(1)];
        let ahead = Vec3::new(ahead.x, 0.0, ahead.z)
            .try_normalize()
            .unwrap_or(Vec3::NEG_Z);
        let mut ranked: Vec<(f32, Vec3)> = (0..LOOK_DIRS)
            .map(|k| {
                let d = level_dir(k);
                let along = d.dot(ahead);
                let fan = LOOK_FAN_DEG.to_radians();
                let open: f32 = [-fan, 0.0, fan]
                    .iter()
                    .map(|&f| reach(eyes[i], glam::Quat::from_rotation_y(f) * d))
                    .sum::<f32>()
                    / 3.0;
                let weight = if along >= 0.0 {
                    0.5 + 0.5 * along
                } else {
                    0.5 + (0.5 - LOOK_BACK) * along
                };
                (open * weight, d)
            })
            .collect();
        ranked.sort_by(|a, b| b.0.total_cmp(&a.0));
        let best_open = ranked[0].0;
        let mut best: Option<(f32, Look)> = None;
        'search: for &(open, dir) in ranked.iter().take(COLOUR_CANDIDATES) {
            if open <= 0.0 || open < 0.25 * best_open {
                break;
            }
            for deg in LOOK_DOWN_DEG {
                let look = Look {
                    dir,
                    down: deg.to_radians().tan(),
                };
                let one = one_colour(eyes[i], look);
                if best.is_none_or(|(b, _)| one < b) {
                    best = Some((one, look));
                }
                if one <= most {
                    break 'search;
                }
            }
        }
        best.unwrap_or((
            1.0,
            Look {
                dir: ranked[0].1,
                down: LOOK_DOWN_DEG[0].to_radians().tan(),
            },
        ))
    });
    (0..n)
        .map(|i| {
            let (a, b) = (raw[i.saturating_sub(1)].1, raw[(i + 1).min(n - 1)].1);
            let (own_share, own) = raw[i];
            let smooth = Look {
                dir: (2.0 * own.dir + a.dir + b.dir)
                    .try_normalize()
                    .unwrap_or(own.dir),
                down: 0.5 * own.down + 0.25 * (a.down + b.down),
            };
            let share = one_colour(eyes[i], smooth);
            if share > most && share > own_share {
                own
            } else {
                smooth
            }
        })
        .collect()
}

/// Poses through `eyes`, each with its view from [`look_dirs`], at a target `reach` away.
fn poses_of(
    rays: &TriangleScene,
    eyes: &[Vec3],
    eye_height: f32,
    reach: f32,
    most: f32,
) -> Vec<CameraPose> {
    look_dirs(rays, eyes, eye_height, most)
        .into_iter()
        .zip(eyes)
        .map(|(look, &eye)| look.at(eye, reach))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A view is judged once per pose and grid, to the value a direct judgement gives.
    #[test]
    fn views_are_judged_once_per_pose_and_grid() {
        // A floor of two colours under a wall.
        let quad = |a: Vec3, b: Vec3, c: Vec3, d: Vec3| [[a, b, c], [a, c, d]];
        let mut tris = Vec::new();
        tris.extend(quad(
            Vec3::new(-10.0, 0.0, -10.0),
            Vec3::new(-10.0, 0.0, 10.0),
            Vec3::new(0.0, 0.0, 10.0),
            Vec3::new(0.0, 0.0, -10.0),
        ));
        tris.extend(quad(
            Vec3::new(0.0, 0.0, -10.0),
            Vec3::new(0.0, 0.0, 10.0),
            Vec3::new(10.0, 0.0, 10.0),
            Vec3::new(10.0, 0.0, -10.0),
        ));
        tris.extend(quad(
            Vec3::new(-10.0, 0.0, -5.0),
            Vec3::new(10.0, 0.0, -5.0),
            Vec3::new(10.0, 5.0, -5.0),
            Vec3::new(-10.0, 5.0, -5.0),
        ));
        let sun = crate::scene::gltf::DEFAULT_SUN.normalize();
        let flat = |c: Vec3, n: Vec3| {
            Some([
                super::super::rays::flat_colour(c, n, sun),
                super::super::rays::flat_colour(c, -n, sun),
            ])
        };
        let (red, blue) = (Vec3::new(0.9, 0.1, 0.1), Vec3::new(0.1, 0.2, 0.9));
        let colours = [
            flat(red, Vec3::Y),
            flat(red, Vec3::Y),
            flat(blue, Vec3::Y),
            flat(blue, Vec3::Y),
            flat(red, Vec3::Z),
            flat(red, Vec3::Z),
        ];
        let rays = TriangleScene::build(&tris, &[], &colours).expect("triangles");
        let views = Views::new(&rays);
        let poses = [
            CameraPose {
                eye: Vec3::new(0.0, 1.7, 2.0),
                target: Vec3::new(0.0, 1.0, -4.0),
            },
            CameraPose {
                eye: Vec3::new(3.0, 1.7, 2.0),
                target: Vec3::new(-2.0, 0.5, -1.0),
            },
        ];
        let grids = [VIEW_RAYS, (10, 6)];
        for _ in 0..2 {
            for pose in &poses {
                for grid in grids {
                    let direct = one_colour_and_back_at(&rays, pose, grid);
                    assert_eq!(views.one_colour_and_back(pose, grid), direct);
                    assert!(direct.0 > 0.0 && direct.0 < 1.0, "{direct:?}");
                }
            }
        }
        assert_eq!(
            views.judged.lock().unwrap().len(),
            poses.len() * grids.len()
        );
    }
}
