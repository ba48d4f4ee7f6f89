//! The walk over places: a graph joining places of neighbouring cells that a person could step
//! between (a step height for stairs and ramps, clearance at the eye and the knees for doorways),
//! its largest connected part, waypoints spread over it (open places far apart along the
//! graph) and a tour through them along shortest paths.

use std::collections::{BinaryHeap, HashMap};

use glam::Vec3;

use super::places::{Place, Scale};
use super::rays::TriangleScene;
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
        seen[start] = true;
        let mut part = vec![start];
        let mut k = 0;
        while k < part.len() {
            for &j in &adj[part[k]] {
                if !seen[j] {
                    seen[j] = true;
                    part.push(j);
                }
            }
            k += 1;
        }
        if part.len() > best.len() {
            best = part;
        }
    }
    best
}

/// Shortest paths from `sources` (cost: length, more near walls through the openness),
/// returning each place's predecessor and distance.
pub fn dijkstra(
    places: &[Place],
    adj: &[Vec<usize>],
    sources: &[usize],
    eye_height: f32,
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
            let nd = d + len * (1.0 + eye_height / places[j].openness.max(1e-3 * eye_height));
            if nd < dist[j] {
                dist[j] = nd;
                prev[j] = i;
                heap.push(Item(nd, j));
            }
        }
    }
    (prev, dist)
}

/// Waypoints over `part`: its most open place, then repeatedly the open place (openness at
/// least the part's median, and a wall no nearer than an eye height where there are such)
/// farthest along the graph from those chosen, up to `count`.
pub fn waypoints(
    places: &[Place],
    adj: &[Vec<usize>],
    part: &[usize],
    count: usize,
    eye_height: f32,
) -> Vec<usize> {
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
    let candidates = if roomy.is_empty() { open } else { roomy };
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
        let (_, dist) = dijkstra(places, adj, &chosen, eye_height);
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
        let (prev, dist) = dijkstra(places, adj, &[current], eye_height);
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
/// open way ahead (see [`look_dirs`]) at a target that far; when the spline through them
/// would come closer than the margin to geometry, every eye is a key.
pub fn keys_through(rays: &TriangleScene, eyes: &[Vec3], s: &Scale) -> Vec<CameraPose> {
    let spacing = (2.5 * s.cell).max(0.8 * s.eye_height);
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
    let path = crate::scene::CameraPath {
        name: String::new(),
        keys: poses_of(rays, &keys, s.eye_height, spacing),
    };
    let frames = path.natural_frames();
    let clear = (0..=frames).all(|f| !rays.within(path.pose_at(f as f32).eye, s.margin));
    if clear {
        path.keys
    } else {
        poses_of(rays, eyes, s.eye_height, spacing)
    }
}

/// Level look directions tried at each key.
const LOOK_DIRS: usize = 24;
/// Half angle of the fan of rays that measures how open one look direction is.
const LOOK_FAN_DEG: f32 = 8.0;
/// Openness counted at most, in eye heights: farther views are all equally good.
const LOOK_CAP: f32 = 25.0;
/// Weight of the look directions behind the way ahead (1 ahead, ½ sideways).
const LOOK_BACK: f32 = 0.3;

/// Look directions at `eyes` (unit, level): at each, the direction whose fan of three rays sees
/// the farthest front faces (a ray that escapes or hits a back face counts as nothing;
/// openness capped at `LOOK_CAP` eye heights), weighted from 1 straight along the way ahead to
/// ½ sideways and `LOOK_BACK` behind; then smoothed with the neighbours' so the view turns
/// gradually. Looks down rooms and corridors rather than at a close wall, turning round when
/// the way ahead ends at one.
pub fn look_dirs(rays: &TriangleScene, eyes: &[Vec3], eye_height: f32) -> Vec<Vec3> {
    let n = eyes.len();
    let far = rays.bounds.extent().length() * 2.0 + 1.0;
    let cap = LOOK_CAP * eye_height;
    let reach = |eye: Vec3, d: Vec3| match rays.hit(eye, d, far) {
        Some(h) if h.front => h.t.min(cap),
        _ => 0.0,
    };
    let raw: Vec<Vec3> = (0..n)
        .map(|i| {
            let ahead = eyes[(i + 2).min(n - 1)] - eyes[i.saturating_sub(1)];
            let ahead = Vec3::new(ahead.x, 0.0, ahead.z)
                .try_normalize()
                .unwrap_or(Vec3::NEG_Z);
            let mut best = (0.0f32, ahead);
            for k in 0..LOOK_DIRS {
                let a = std::f32::consts::TAU * k as f32 / LOOK_DIRS as f32;
                let d = Vec3::new(a.cos(), 0.0, a.sin());
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
                let score = open * weight;
                if score > best.0 {
                    best = (score, d);
                }
            }
            best.1
        })
        .collect();
    (0..n)
        .map(|i| {
            let (a, b) = (raw[i.saturating_sub(1)], raw[(i + 1).min(n - 1)]);
            (2.0 * raw[i] + a + b).try_normalize().unwrap_or(raw[i])
        })
        .collect()
}

/// How far below level the walk looks: a person walking looks a little down, and the view
/// then shows the floor ahead rather than a wall above it (or sky over a roofless level).
const LOOK_DOWN_DEG: f32 = 10.0;

/// Poses through `eyes`, each looking along [`look_dirs`], `LOOK_DOWN_DEG` down, at a target
/// `reach` away.
fn poses_of(rays: &TriangleScene, eyes: &[Vec3], eye_height: f32, reach: f32) -> Vec<CameraPose> {
    let down = Vec3::NEG_Y * LOOK_DOWN_DEG.to_radians().tan();
    look_dirs(rays, eyes, eye_height)
        .into_iter()
        .zip(eyes)
        .map(|(dir, &eye)| CameraPose {
            eye,
            target: eye + (dir + down).normalize() * reach,
        })
        .collect()
}
