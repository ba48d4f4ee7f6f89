//! The decision trace of every CHC-family culler, pinned: on the deterministic [`MockBackend`]
//! each configuration (chc, chcpp, nohc, chcpp's parts alone, the latency modes with one and
//! two frames in flight) walks a recorded camera path through a procedural city, and every
//! frame's ordered backend calls (draws with their objects, queries with purpose, box count
//! and answer, state restores, flushes, waits, predicate resolves, predicated draws, the end
//! of the frame) and the culler's own statistics are reduced to a 64-bit FNV-1a digest. The
//! digests must equal those in `tests/data/decisions.txt`: a refactor of the traversal that
//! changes no decision passes, anything else names the configuration and the first frame that
//! differs, with that frame's calls.
//!
//! To rewrite the golden file after an intended change of behaviour:
//! `COHERENT_BLESS=1 cargo test -p coherent-cull --test decisions`.

use std::cell::RefCell;
use std::fmt::Write as _;

use coherent_cull::camera::{Camera, CameraPose, Frustum};
use coherent_cull::chcpp::{Chcpp, ChcppParams};
use coherent_cull::glam::Vec3;
use coherent_cull::rng::Rng;
use coherent_cull::testing::{Completion, MockBackend, MockEvent};
use coherent_cull::{
    create_with, Aabb, CostModel, CullStats, Culler, CullerSetup, FrameInput, Latency, NohcParams,
    ObjectBvh, QueryPurpose,
};

const GOLDEN: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/decisions.txt");
const FRAMES: u64 = 120;
/// Blocks per side of the city, the distance between block origins, a building's side.
const BLOCKS: u32 = 5;
const PITCH: f32 = 30.0;
const BUILDING: f32 = 20.0;

/// The city: objects (buildings, things hidden inside them, things in the streets) and the
/// walls that occlude (the buildings, a little shrunk so that their own boxes can be seen).
struct City {
    objects: Vec<Aabb>,
    triangles: Vec<u32>,
    walls: Vec<Aabb>,
}

fn city() -> City {
    let mut rng = Rng::new(0xC17E);
    let mut c = City {
        objects: Vec::new(),
        triangles: Vec::new(),
        walls: Vec::new(),
    };
    for i in 0..BLOCKS {
        for j in 0..BLOCKS {
            let o = Vec3::new(i as f32 * PITCH, 0.0, j as f32 * PITCH);
            let height = rng.range(6.0, 30.0);
            let building = Aabb::new(o, o + Vec3::new(BUILDING, height, BUILDING));
            c.objects.push(building);
            c.triangles.push(2_000);
            c.walls
                .push(Aabb::new(building.min + 0.2, building.max - 0.2));
            // Machinery inside: never seen, the multiqueries' favourite.
            for _ in 0..3 {
                let p = o + Vec3::new(rng.range(2.0, 15.0), 0.5, rng.range(2.0, 15.0));
                c.objects
                    .push(Aabb::new(p, p + Vec3::splat(rng.range(1.0, 3.0))));
                c.triangles.push(40_000);
            }
        }
    }
    // Crates, cars and posts in the streets (and the open ground around the city).
    let extent = BLOCKS as f32 * PITCH;
    while c.objects.len() < 360 {
        let p = Vec3::new(rng.range(-10.0, extent), 0.0, rng.range(-10.0, extent));
        let cell = |v: f32| v.rem_euclid(PITCH) < BUILDING + 0.5 && (0.0..extent).contains(&v);
        if cell(p.x) && cell(p.z) {
            continue; // inside a block
        }
        let size = Vec3::new(
            rng.range(0.5, 4.0),
            rng.range(0.5, 3.0),
            rng.range(0.5, 4.0),
        );
        c.objects.push(Aabb::new(p, p + size));
        c.triangles.push(12 + rng.below(3_000));
    }
    c
}

/// Frame `f` of the path: down the street between the first and second rows of blocks, a
/// turn into the cross street, a cut to a bird's-eye view circling the city, a cut back to the
/// ground at the far side.
fn camera(f: u64) -> Camera {
    let street = |i: f32| i * PITCH + BUILDING + 5.0;
    let (eye, target) = match f {
        0..=40 => {
            let eye = Vec3::new(-5.0 + 2.2 * f as f32, 1.7, street(0.0));
            (eye, eye + Vec3::X)
        }
        41..=55 => {
            let a = (f - 40) as f32 / 15.0 * std::f32::consts::FRAC_PI_2;
            let eye = Vec3::new(street(2.0), 1.7, street(0.0));
            (eye, eye + Vec3::new(a.cos(), 0.0, a.sin()))
        }
        56..=75 => {
            let eye = Vec3::new(street(2.0), 1.7, street(0.0) + 2.0 * (f - 55) as f32);
            (eye, eye + Vec3::Z)
        }
        76..=95 => {
            let a = (f - 76) as f32 * 0.05;
            let c = Vec3::new(75.0, 0.0, 75.0);
            (c + Vec3::new(a.cos() * 160.0, 90.0, a.sin() * 160.0), c)
        }
        _ => {
            let eye = Vec3::new(street(3.0), 1.7, 140.0 - 2.5 * (f - 96) as f32);
            (eye, eye + Vec3::new(-0.3, 0.0, -1.0))
        }
    };
    Camera::from_pose(CameraPose { eye, target }, 16.0 / 9.0, 400.0)
}

/// What the camera can see this frame: a box sees 10 pixels per sample point (its centre and
/// its corners pulled a little inwards) in the frustum's box test whose segment to the eye no
/// wall cuts.
struct Sight {
    eye: Vec3,
    frustum: Frustum,
    walls: Vec<Aabb>,
}

impl Sight {
    fn pixels(&self, b: &Aabb) -> u64 {
        if !b.is_valid() || !self.frustum.intersects(b) {
            return 0;
        }
        let c = b.center();
        let corners = b.corners().map(|p| c.lerp(p, 0.9));
        let samples = std::iter::once(c).chain(corners);
        10 * samples.filter(|&p| !self.blocked(p)).count() as u64
    }

    /// Whether a wall cuts the segment from the eye to `p` (slab test, `p` itself excluded).
    fn blocked(&self, p: Vec3) -> bool {
        let d = p - self.eye;
        self.walls.iter().any(|w| {
            let (mut t0, mut t1) = (0.0f32, 0.999f32);
            for a in 0..3 {
                if d[a].abs() < 1e-9 {
                    if self.eye[a] < w.min[a] || self.eye[a] > w.max[a] {
                        return false;
                    }
                    continue;
                }
                let (u, v) = (
                    (w.min[a] - self.eye[a]) / d[a],
                    (w.max[a] - self.eye[a]) / d[a],
                );
                t0 = t0.max(u.min(v));
                t1 = t1.min(u.max(v));
            }
            t0 <= t1
        })
    }
}

/// One configuration: a culler and the backend it runs on.
struct Config {
    name: &'static str,
    culler: Box<dyn Culler>,
    completion: Completion,
    frames_in_flight: u32,
    /// The backend issues queries under predicates (the predicated mode splits nodes).
    predicated_queries: bool,
}

fn latency(name: &'static str, params: ChcppParams, latency: Latency, k: u32) -> Config {
    Config {
        name,
        culler: Box::new(
            Chcpp::new(params)
                .with_latency(latency)
                .with_frames_in_flight(k),
        ),
        completion: Completion::AfterSubmit,
        frames_in_flight: k,
        predicated_queries: false,
    }
}

/// A predicated configuration on a backend that queries under predicates.
fn split(name: &'static str, params: ChcppParams, k: u32) -> Config {
    Config {
        predicated_queries: true,
        ..latency(name, params, Latency::Predicated, k)
    }
}

fn plain(name: &'static str, culler: Box<dyn Culler>, completion: Completion) -> Config {
    Config {
        name,
        culler,
        completion,
        frames_in_flight: 1,
        predicated_queries: false,
    }
}

fn configs(city: &City) -> Vec<Config> {
    let nohc = CullerSetup {
        nohc: Some(NohcParams::new(
            CostModel {
                draw_ms: 0.06,
                triangle_ms: 2e-5,
                fragment_ms: 2e-6,
                query_ms: 0.1,
                query_fragment_ms: 1e-6,
                round_trip_ms: 0.3,
            },
            (640, 360),
            city.triangles.clone(),
        )),
        ..CullerSetup::default()
    };
    let chcpp = ChcppParams::default;
    let only = |parts: &[&str]| Box::new(Chcpp::new(ChcppParams::only(parts)));
    let setup = CullerSetup::default();
    let named = |name| create_with(name, &setup).unwrap();
    vec![
        plain("chc", named("chc"), Completion::AfterSubmit),
        plain("chc@on-wait", named("chc"), Completion::OnWait),
        plain("chcpp", named("chcpp"), Completion::AfterSubmit),
        plain("chcpp@on-wait", named("chcpp"), Completion::OnWait),
        plain(
            "nohc",
            create_with("nohc", &nohc).unwrap(),
            Completion::AfterSubmit,
        ),
        plain(
            "nohc@on-wait",
            create_with("nohc", &nohc).unwrap(),
            Completion::OnWait,
        ),
        plain("chcpp-batching", only(&["batching"]), Completion::OnWait),
        plain(
            "chcpp-interval",
            only(&["interval"]),
            Completion::AfterSubmit,
        ),
        plain(
            "chcpp-multiqueries",
            only(&["multiqueries"]),
            Completion::OnWait,
        ),
        plain("chcpp-tight", only(&["tight"]), Completion::AfterSubmit),
        latency("chcpp@next-frame", chcpp(), Latency::NextFrame, 1),
        latency("chcpp@next-frame-k2", chcpp(), Latency::NextFrame, 2),
        latency(
            "chcpp@next-frame-conservative",
            chcpp(),
            Latency::NextFrameConservative,
            1,
        ),
        latency(
            "chcpp@next-frame-conservative-k2",
            chcpp(),
            Latency::NextFrameConservative,
            2,
        ),
        latency("chcpp@predicated", chcpp(), Latency::Predicated, 1),
        latency("chcpp@predicated-k2", chcpp(), Latency::Predicated, 2),
        latency("chc@next-frame", ChcppParams::chc(), Latency::NextFrame, 1),
        latency(
            "chc@next-frame-conservative",
            ChcppParams::chc(),
            Latency::NextFrameConservative,
            1,
        ),
        latency("chc@predicated", ChcppParams::chc(), Latency::Predicated, 1),
        split("chcpp@predicated-split", chcpp(), 1),
        split("chcpp@predicated-split-k2", chcpp(), 2),
        split("chc@predicated-split", ChcppParams::chc(), 1),
    ]
}

/// FNV-1a, 64 bits.
struct Fnv(u64);

impl Fnv {
    fn new() -> Fnv {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
    fn bytes(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
    }
    fn u32(&mut self, v: u32) {
        self.bytes(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }
    fn objects(&mut self, objects: &[u32]) {
        self.u32(objects.len() as u32);
        objects.iter().for_each(|&o| self.u32(o));
    }
}

fn digest_event(h: &mut Fnv, e: &MockEvent) {
    match e {
        MockEvent::Draw(objects) => {
            h.u32(1);
            h.objects(objects);
        }
        MockEvent::Query {
            id,
            purpose,
            boxes,
            visible,
        } => {
            h.u32(2);
            h.u32(*id);
            h.u32(match purpose {
                QueryPurpose::Node => 0,
                QueryPurpose::Multiquery => 1,
                QueryPurpose::VisibleLeaf => 2,
            });
            h.u64(*boxes as u64);
            h.u32(u32::from(*visible));
        }
        MockEvent::RestoreRenderState => h.u32(3),
        MockEvent::Flush => h.u32(4),
        MockEvent::Wait(id) => {
            h.u32(5);
            h.u32(*id);
        }
        MockEvent::EndOfFrame => h.u32(6),
        MockEvent::Resolve => h.u32(7),
        MockEvent::DrawIf {
            query,
            objects,
            taken,
        } => {
            h.u32(8);
            h.u32(*query);
            h.objects(objects);
            h.u32(u32::from(*taken));
        }
        MockEvent::QueryIf {
            id,
            predicate,
            boxes,
            visible,
        }
        | MockEvent::PartTest {
            id,
            predicate,
            boxes,
            visible,
        } => {
            h.u32(if matches!(e, MockEvent::QueryIf { .. }) {
                9
            } else {
                10
            });
            h.u32(*id);
            h.u32(*predicate);
            h.u64(*boxes as u64);
            h.u32(u32::from(*visible));
        }
    }
}

fn digest_stats(h: &mut Fnv, s: &CullStats) {
    let fields = [
        s.nodes_visited,
        s.objects_drawn,
        s.queries,
        s.invisible_node_queries,
        s.invisible_nodes_tested,
        s.visible_leaf_queries,
        s.multiqueries,
        s.failed_multiqueries,
        s.visible_results,
        s.query_batches,
        s.full_batches,
        s.requeried,
        s.predicate_resolves,
        s.predicated_draws,
        s.predicated_objects,
        s.blocking_waits,
        s.frustum_culled,
        s.query_culled,
    ];
    fields.iter().for_each(|&v| h.u32(v));
}

/// A configuration's walk: per-frame digests, readable totals and every frame's events (for
/// the report of a mismatch).
struct Trace {
    frames: Vec<u64>,
    totals: Totals,
    events: Vec<Vec<MockEvent>>,
}

#[derive(Default)]
struct Totals {
    draws: u32,
    objects: u32,
    queries: u32,
    batches: u32,
    state_changes: u32,
    submits: u32,
    waits: u32,
    resolves: u32,
    draw_ifs: u32,
}

fn walk(city: &City, mut config: Config) -> Trace {
    let mut bvh = ObjectBvh::build(&city.objects, 1);
    let sight = RefCell::new(Sight {
        eye: Vec3::ZERO,
        frustum: camera(1).frustum(),
        walls: city.walls.clone(),
    });
    let mut backend = MockBackend::new(|b: &Aabb| sight.borrow().pixels(b))
        .with_completion(config.completion)
        .with_frames_in_flight(config.frames_in_flight);
    if !config.predicated_queries {
        backend = backend.without_predicated_queries();
    }
    let mover = city.objects.len() as u32 - 1;
    let mut added = None;
    let mut trace = Trace {
        frames: Vec::new(),
        totals: Totals::default(),
        events: Vec::new(),
    };
    for f in 1..=FRAMES {
        // The world between frames: a car drives down the cross street, a crate appears and
        // later goes, the hierarchy is rebuilt once, the culler is reset at the second cut.
        let z = 160.0 - 3.0 * f as f32;
        let x = 2.0 * PITCH + BUILDING + 3.0;
        bvh.set_bounds(mover, [[x, 0.0, z], [x + 2.0, 1.5, z + 4.0]])
            .unwrap();
        if f == 30 {
            let x = PITCH + BUILDING + 2.0;
            let z = BUILDING + 4.0;
            added = Some(bvh.insert([[x, 0.0, z], [x + 1.0, 1.0, z + 1.0]]));
        }
        if f == 90 {
            bvh.remove(added.unwrap()).unwrap();
        }
        bvh.update();
        if f == 60 {
            bvh.rebuild();
        }
        if f == 96 {
            config.culler.reset();
        }
        let cam = camera(f);
        *sight.borrow_mut() = Sight {
            eye: cam.eye,
            frustum: cam.frustum(),
            walls: city.walls.clone(),
        };
        let input = FrameInput {
            bvh: &bvh,
            view: (&cam).into(),
            frame: f,
            exact_visible: None,
        };
        let stats = config.culler.cull_frame(&input, &mut backend).unwrap();
        let mut h = Fnv::new();
        backend
            .events()
            .iter()
            .for_each(|e| digest_event(&mut h, e));
        digest_stats(&mut h, &stats);
        trace.frames.push(h.0);
        let c = backend.counts();
        let t = &mut trace.totals;
        t.draws += c.draw_calls;
        t.objects += c.objects_drawn;
        t.queries += c.queries;
        t.batches += stats.query_batches;
        t.state_changes += c.state_changes;
        t.submits += c.submits;
        t.waits += c.waits;
        t.resolves += c.resolves;
        t.draw_ifs += c.predicated_draws;
        trace.events.push(backend.events().to_vec());
        backend.end_frame();
    }
    trace
}

/// A configuration's block in the golden file: a line with the digest of the whole walk and
/// its totals, then the frames' digests (32 bits each), ten a line.
fn block(name: &str, trace: &Trace) -> String {
    let mut whole = Fnv::new();
    trace.frames.iter().for_each(|&d| whole.u64(d));
    let t = &trace.totals;
    let mut s = format!(
        "{name} {:016x} draws={} objects={} queries={} batches={} state_changes={} submits={} \
         waits={} resolves={} draw_ifs={}\n",
        whole.0,
        t.draws,
        t.objects,
        t.queries,
        t.batches,
        t.state_changes,
        t.submits,
        t.waits,
        t.resolves,
        t.draw_ifs
    );
    for (i, chunk) in trace.frames.chunks(10).enumerate() {
        let digests: Vec<String> = chunk.iter().map(|d| format!("{:08x}", d >> 32)).collect();
        writeln!(s, "  {:3}: {}", i * 10 + 1, digests.join(" ")).unwrap();
    }
    s
}

/// The frames' digests of a block (`None` when the golden file has no such block).
fn golden_frames(golden: &str, name: &str) -> Option<(String, Vec<String>)> {
    let mut lines = golden.lines();
    let header = lines.find(|l| l.split(' ').next() == Some(name))?;
    let frames = lines
        .take_while(|l| l.starts_with("  "))
        .flat_map(|l| l.split_once(": ").unwrap().1.split(' '))
        .map(str::to_string)
        .collect();
    Some((header.to_string(), frames))
}

#[test]
fn chc_chcpp_and_nohc_decide_as_recorded() {
    let city = city();
    let mut out = String::from(
        "# Decision digests of tests/decisions.rs: one block per configuration (digest of the\n\
         # walk, totals), then each frame's digest (high 32 bits), ten a line.\n\
         # Rewrite with COHERENT_BLESS=1 cargo test -p coherent-cull --test decisions.\n",
    );
    let mut traces = Vec::new();
    for config in configs(&city) {
        let name = config.name;
        let trace = walk(&city, config);
        out.push_str(&block(name, &trace));
        traces.push((name, trace));
    }
    // The scene exercises both answers, and every kind of call somewhere.
    let total = |f: fn(&Totals) -> u32| traces.iter().map(|(_, t)| f(&t.totals)).sum::<u32>();
    assert!(total(|t| t.waits) > 0 && total(|t| t.resolves) > 0 && total(|t| t.draw_ifs) > 0);
    let answers: Vec<bool> = traces
        .iter()
        .flat_map(|(_, t)| t.events.iter().flatten())
        .filter_map(|e| match e {
            MockEvent::Query { visible, .. } => Some(*visible),
            _ => None,
        })
        .collect();
    assert!(answers.contains(&true) && answers.contains(&false));

    if std::env::var_os("COHERENT_BLESS").is_some() {
        std::fs::create_dir_all(std::path::Path::new(GOLDEN).parent().unwrap()).unwrap();
        std::fs::write(GOLDEN, &out).unwrap();
        return;
    }
    let golden = std::fs::read_to_string(GOLDEN)
        .expect("tests/data/decisions.txt (write it with COHERENT_BLESS=1)");
    let mut failures = Vec::new();
    for (name, trace) in &traces {
        let ours = block(name, trace);
        let header = ours.lines().next().unwrap();
        let Some((want_header, want_frames)) = golden_frames(&golden, name) else {
            failures.push(format!("{name}: not in the golden file"));
            continue;
        };
        if want_header == header {
            continue;
        }
        let first = trace
            .frames
            .iter()
            .zip(&want_frames)
            .position(|(d, w)| format!("{:08x}", d >> 32) != *w)
            .unwrap_or(trace.frames.len().min(want_frames.len()));
        let mut report = format!(
            "{name}: decisions differ from frame {}\n  want: {want_header}\n  got:  {header}\n  \
             frame {}'s calls now:\n",
            first + 1,
            first + 1
        );
        let events = trace.events.get(first).map_or(&[][..], Vec::as_slice);
        for e in events.iter().take(60) {
            writeln!(report, "    {e:?}").unwrap();
        }
        if events.len() > 60 {
            writeln!(report, "    ... {} more", events.len() - 60).unwrap();
        }
        failures.push(report);
    }
    assert!(
        failures.is_empty(),
        "{}\n(if the change is intended: COHERENT_BLESS=1 cargo test -p coherent-cull --test decisions)",
        failures.join("\n")
    );
}
