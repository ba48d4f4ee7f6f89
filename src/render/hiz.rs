//! Two-phase Hi-Z GPU culling (`hiz`): the GPU-driven alternative to hardware occlusion
//! queries, run by the same renderer on the same target, and counted by the same recorder.
//!
//! Design. Object bounds and draw ranges live in a storage buffer; a per-object flag word
//! holds "visible last frame" (bit 0) and "drawn in phase 1" (bit 1). A frame is one command
//! buffer, with no CPU readback inside it:
//! 1. **Phase 1** (hiz_cull.comp, phase 1): objects visible last frame are tested against the
//!    frustum and, when the previous frame left one, against its depth pyramid (with this
//!    frame's camera: a heuristic, since phase 2 re-tests whatever it culls); survivors get an
//!    indexed indirect draw command and bit 1. One `vkCmdDrawIndexedIndirectCount` draws them
//!    (clearing color and depth first).
//! 2. **Pyramid** (hiz_reduce.comp): the depth buffer, now holding the phase-1 occluders, is
//!    reduced into a mip chain of the farthest depth ([`pyramid`]).
//! 3. **Phase 2** (hiz_cull.comp, phase 2): every object is tested against the frustum and the
//!    new pyramid; visible ones not drawn in phase 1 are drawn by a second indirect draw (LOAD
//!    ops). The same pass writes each object's flag for the next frame (visible or not).
//!
//! Exactness: phase 2 tests everything that phase 1 did not draw against a pyramid built from
//! depth that is a subset of the final depth, and the test is conservative (boxes crossing the
//! near plane are visible; a box is culled only when its nearest depth, less a small margin, is
//! farther than the farthest depth of every pyramid texel under its screen rectangle), so an
//! object that covers a pixel of the final image is always drawn — on the first frame (no flags,
//! nothing in phase 1) and after a camera cut alike. Moving objects (`--movers`): their boxes
//! are uploaded again before a frame when the renderer's have changed.
//!
//! Materials: objects that bind the same things (texture set, alpha cutoff, two-sided) form a
//! group, each with its own stretch of the command buffer and its own counter per phase; each
//! phase draws a group with one indirect draw after binding what the group's objects bind in
//! the forward pass. So textured, masked and two-sided objects look as they do with every
//! other algorithm, and masked ones write depth only where they are drawn (the pyramid sees
//! through their holes). A scene without materials is one group. Blended objects (glTF BLEND)
//! are not culled here: their ranges are empty, and phase 2's rendering ends with them, drawn
//! (and the heavy ones tested) by the renderer back to front as after every other
//! algorithm's frame.
//!
//! Counts come from the recorder: dispatches (2 cull + one per pyramid level), an indirect
//! draw per group and phase, pipeline and texture binds; the objects and triangles those
//! draws drew are read back from the GPU's counters after the frame (for the report only).

pub mod pyramid;

use std::sync::Arc;
use std::time::Instant;

use ash::vk;
use gpu_allocator::MemoryLocation;

use crate::bvh::ObjectBvh;
use crate::culling::{self, ChcppParams, CullStats, Culler};
use crate::error::{Error, Result};
use crate::gpu::{
    as_bytes, bytes_of, shaders, word_at, Access, Binding, Buffer, ComputePipeline, DescriptorSets,
    GpuContext, PipelineLayout,
};
use crate::scene::camera::Camera;
use pyramid::DepthPyramid;

use super::{FrameResult, Renderer};

/// Objects per workgroup of the culling shader (hiz_cull.comp: 64).
const GROUP: u32 = 64;
/// Bytes of one object's record in the bounds buffer (hiz_cull.comp `ObjectBounds`).
const BOUNDS_BYTES: u64 = 64;
/// Bytes of the counters buffer before the per-group draw counts (hiz_cull.comp `Counters`).
const COUNTS_AT: u64 = 16;
/// Bytes of one `VkDrawIndexedIndirectCommand`.
const COMMAND_BYTES: u64 = 20;
/// Push constants of the culling shader: view_proj, info, screen.
const CULL_PUSH: u32 = 96;

/// Parameters of the Hi-Z culler.
#[derive(Clone, Copy, Debug)]
pub struct HizParams {
    /// Test phase-1 objects against the previous frame's pyramid (else frustum only).
    pub phase1_occlusion: bool,
    /// Depth margin of the occlusion test: a box is culled only when its nearest depth minus
    /// this is farther than the pyramid (guards against rounding between the projected box and
    /// the rasterized depth).
    pub depth_margin: f32,
    /// Most pyramid texels per side read for one box: the test uses the finest level where
    /// the box's screen rectangle spans at most this many (2 is the classic 2x2 fetch; more
    /// fetches test against finer depth and cull more).
    pub texels_per_side: u32,
}

impl Default for HizParams {
    fn default() -> Self {
        HizParams {
            phase1_occlusion: true,
            depth_margin: 1e-6,
            texels_per_side: 4,
        }
    }
}

/// The two-phase Hi-Z culler for one [`Renderer`] (its scene and target size).
pub struct HizCuller {
    ctx: Arc<GpuContext>,
    params: HizParams,
    object_count: u32,
    size: (u32, u32),
    cull: ComputePipeline,
    cull_layout: PipelineLayout,
    cull_sets: DescriptorSets,
    pyramid: DepthPyramid,
    /// Whether the pyramid holds a previous frame's depth.
    pyramid_valid: bool,
    /// Objects drawn by phase 1 and phase 2 of the last frame (read back).
    last_phases: [u32; 2],
    /// The objects of one draw class: their commands' stretch and one object of theirs.
    groups: Vec<Group>,
    /// Each group's draws in both phases of the last frame, phase 1's groups first (read
    /// back; kept to be refilled without allocating).
    group_counts: Vec<u32>,
    /// Device time of each pass of the last frame ([`PASSES`]), from timestamps.
    last_pass_ms: [f64; 5],
    /// Per object: world bounds and draw parameters (the descriptor set points at it).
    bounds: Buffer,
    flags: Buffer,
    draws: Buffer,
    counters: Buffer,
    /// With [`HizCuller::log_drawn_objects`]: a host copy of the frame's draw commands, and
    /// the objects they drew (for `walk --check`).
    readback: Option<Buffer>,
    drawn: Vec<u32>,
    /// The renderer's bounds version that `bounds` holds (objects that moved are re-uploaded).
    bounds_version: u64,
}

impl HizCuller {
    /// Creates the buffers, pyramid and pipelines for `renderer`'s scene and target. Fails
    /// with [`Error::Unsupported`] when the device lacks a feature or limit it needs.
    pub fn new(renderer: &Renderer, params: HizParams) -> Result<HizCuller> {
        let ctx = renderer.context().clone();
        let n = renderer.draw_ranges().len() as u32;
        check_device(&ctx, n)?;
        let ranges: Vec<super::DrawRange> = renderer.draw_ranges().collect();
        let (groups, group_of) = Group::of(&ranges);
        let g = groups.len() as u32;
        let mut records: Vec<u32> = Vec::with_capacity(n as usize * 16);
        for (o, &k) in ranges.iter().zip(&group_of) {
            let (lo, hi) = (o.bounds.min, o.bounds.max);
            let corners = [lo.x, lo.y, lo.z, 0.0, hi.x, hi.y, hi.z, 0.0];
            records.extend(corners.map(f32::to_bits));
            records.extend([o.index_count, o.first_index, o.vertex_offset as u32, 0]);
            records.extend([groups[k as usize].first_slot, k, g + k, 0]);
        }
        let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
        let indirect =
            storage | vk::BufferUsageFlags::INDIRECT_BUFFER | vk::BufferUsageFlags::TRANSFER_SRC;
        let bounds = Buffer::with_data(&ctx, "hiz bounds", &as_bytes(&records), storage)?;
        let flags = Buffer::with_data(&ctx, "hiz flags", &vec![0u8; 4 * n as usize], storage)?;
        let draws = Buffer::new(
            &ctx,
            "hiz draws",
            2 * n.max(1) as u64 * COMMAND_BYTES,
            indirect,
            MemoryLocation::GpuOnly,
        )?;
        let counters = Buffer::new(
            &ctx,
            "hiz counters",
            COUNTS_AT + 8 * u64::from(g),
            indirect | vk::BufferUsageFlags::TRANSFER_DST,
            MemoryLocation::GpuToCpu,
        )?;
        let pyramid = DepthPyramid::new(&ctx, renderer.depth_target())?;
        let cull_layout = PipelineLayout::new(
            &ctx,
            &[
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::STORAGE_BUFFER,
                vk::DescriptorType::COMBINED_IMAGE_SAMPLER,
            ],
            CULL_PUSH,
        )?;
        let cull = ComputePipeline::new(&ctx, &cull_layout, "hiz cull", shaders::HIZ_CULL_COMP)?;
        let cull_bindings = [
            Binding::StorageBuffer(&bounds),
            Binding::StorageBuffer(&flags),
            Binding::StorageBuffer(&draws),
            Binding::StorageBuffer(&counters),
            Binding::SampledMips(&pyramid.image, None, &pyramid.sampler),
        ];
        let cull_sets = DescriptorSets::new(&ctx, &[(&cull_layout, &cull_bindings[..])])?;
        Ok(HizCuller {
            ctx,
            params,
            object_count: n,
            size: renderer.size(),
            cull,
            cull_layout,
            cull_sets,
            pyramid,
            pyramid_valid: false,
            last_phases: [0; 2],
            group_counts: vec![0; 2 * groups.len()],
            groups,
            last_pass_ms: [0.0; 5],
            bounds,
            flags,
            draws,
            counters,
            readback: None,
            drawn: Vec::new(),
            bounds_version: renderer.bounds_version(),
        })
    }

    /// Re-uploads every object's bounds when the renderer's changed (moving objects).
    fn sync_bounds(&mut self, r: &Renderer) -> Result<()> {
        if r.bounds_version() == self.bounds_version {
            return Ok(());
        }
        for (i, o) in r.draw_ranges().take(self.object_count as usize).enumerate() {
            let (lo, hi) = (o.bounds.min, o.bounds.max);
            let corners = [lo.x, lo.y, lo.z, 0.0, hi.x, hi.y, hi.z, 0.0];
            self.bounds
                .write(i * BOUNDS_BYTES as usize, bytes_of(&corners))?;
        }
        self.bounds_version = r.bounds_version();
        Ok(())
    }

    /// Turns on (or off) copying each frame's draw commands back to the host, so that
    /// [`HizCuller::drawn_objects`] knows what the GPU drew (`walk --check`; costs a copy).
    pub fn log_drawn_objects(&mut self, on: bool) -> Result<()> {
        self.readback = if on {
            Some(Buffer::new(
                &self.ctx,
                "hiz draws readback",
                2 * u64::from(self.object_count.max(1)) * COMMAND_BYTES,
                vk::BufferUsageFlags::TRANSFER_DST,
                MemoryLocation::GpuToCpu,
            )?)
        } else {
            None
        };
        self.drawn.clear();
        Ok(())
    }

    /// The objects the last frame's indirect draws drew (both phases), when logging is on.
    pub fn drawn_objects(&self) -> &[u32] {
        &self.drawn
    }

    /// Reads the draw commands of both phases from the readback copy: each command's
    /// `firstInstance` is its object; `group_counts` says how many each group drew.
    fn read_drawn(&mut self) -> Result<()> {
        self.drawn.clear();
        let Some(bytes) = self.readback.as_ref().and_then(|b| b.mapped()) else {
            return Ok(());
        };
        let n = self.object_count as usize;
        let groups = self.groups.len();
        for phase in 0..2 {
            for (k, g) in self.groups.iter().enumerate() {
                let count = self.group_counts[phase * groups + k];
                for slot in 0..(count.min(g.size)) as usize {
                    let command = phase * n + g.first_slot as usize + slot;
                    let at = command * COMMAND_BYTES as usize + 16;
                    let word = bytes.get(at..at + 4).ok_or_else(|| {
                        Error::Alloc("hiz draws readback is shorter than its commands".into())
                    })?;
                    self.drawn
                        .push(u32::from_le_bytes([word[0], word[1], word[2], word[3]]));
                }
            }
        }
        Ok(())
    }

    /// Forgets temporal state: no object counts as visible last frame, no pyramid is reused.
    pub fn reset(&mut self) -> Result<()> {
        self.ctx.wait_idle()?;
        self.flags
            .write(0, &vec![0u8; 4 * self.object_count as usize])?;
        self.pyramid_valid = false;
        Ok(())
    }

    /// Renders one frame into `r`'s target: phase 1, pyramid, phase 2, in one submission.
    pub fn render_frame(&mut self, r: &mut Renderer, camera: &Camera) -> Result<FrameResult> {
        if r.size() != self.size {
            return Err(Error::Input(format!(
                "hiz culler made for {}x{}, renderer is {}x{}",
                self.size.0,
                self.size.1,
                r.size().0,
                r.size().1
            )));
        }
        self.sync_bounds(r)?;
        r.begin_frame(&camera.into())?;
        let start = Instant::now();
        r.begin_segment()?;
        r.write_timestamp()?;
        let vp = camera.view_proj().to_cols_array();
        // Moves a new pyramid to GENERAL before phase 1's set refers to it; later frames keep
        // its contents (the previous frame's pyramid).
        r.recorder_mut().mip_barrier(
            &mut self.pyramid.image,
            Access::ComputeReadWrite,
            Access::ComputeReadWrite,
        );
        self.record_phase(r, 1, &vp)?;
        let (rec, depth) = r.recorder_and_depth();
        self.pyramid.record_build(rec, depth)?;
        r.write_timestamp()?;
        self.record_phase(r, 2, &vp)?;
        let rec = r.recorder_mut();
        if let Some(readback) = &self.readback {
            rec.memory_barrier(Access::ComputeReadWrite, Access::TransferRead);
            let bytes = 2 * u64::from(self.object_count.max(1)) * COMMAND_BYTES;
            rec.copy_buffer(&self.draws, readback, bytes);
            rec.memory_barrier(Access::TransferWrite, Access::HostRead);
        }
        rec.memory_barrier(Access::ComputeReadWrite, Access::HostRead);
        r.submit_and_wait()?;
        let frame_time = start.elapsed();
        r.read_blended_tests()?;
        let frame_ms = frame_time.as_secs_f64() * 1e3;
        let cpu_ms = r.cpu_ms(start, frame_time);
        self.pyramid_valid = true;
        let triangles = self.read_counters()?;
        let (first, second) = self.group_counts.split_at(self.groups.len());
        let phases = [first.iter().sum::<u32>(), second.iter().sum::<u32>()];
        self.last_phases = phases;
        self.read_drawn()?;
        let objects = phases[0] + phases[1];
        let movers = r.mover_objects();
        let moving = self.drawn.iter().filter(|o| movers.contains(o)).count();
        let gpu_ms = self.read_pass_times(r)?;
        // What the indirect draws drew is known only now, read back from the GPU.
        let mut counts = r.recorder_mut().take_counts();
        r.add_frame_query_counts(&mut counts)?;
        counts.indirect_objects += objects;
        counts.indirect_triangles += triangles;
        counts.mover_draws += moving as u32;
        Ok(FrameResult {
            frame_ms,
            gpu_ms,
            stall_ms: 0.0,
            cpu_ms,
            counts,
            cull: CullStats {
                objects_drawn: objects,
                ..Default::default()
            },
            // The draws are generated on the GPU: `walk --check` reads them back
            // (`log_drawn_objects`) and checks them with `Renderer::check_objects`.
            check: None,
        })
    }

    /// Records one phase: the culling dispatch that writes indirect draws, then the draw.
    fn record_phase(&mut self, r: &mut Renderer, phase: u32, view_proj: &[f32; 16]) -> Result<()> {
        let margin = super::part_tests::centre_margin(r.pixel_grid);
        let rec = r.recorder_mut();
        if phase == 1 {
            let bytes = COUNTS_AT + 8 * self.groups.len() as u64;
            rec.fill_buffer(&self.counters, 0, bytes, 0);
            rec.memory_barrier(Access::TransferWrite, Access::ComputeReadWrite);
        } else {
            rec.memory_barrier(Access::IndirectRead, Access::ComputeReadWrite);
        }
        let levels = if phase == 2 || (self.pyramid_valid && self.params.phase1_occlusion) {
            self.pyramid.image.levels()
        } else {
            0
        };
        let (w, h) = self.size;
        let info = [
            self.object_count,
            phase,
            levels,
            self.params.texels_per_side.max(2),
        ];
        let screen = [w as f32, h as f32, self.params.depth_margin, margin];
        let mut push = [0u8; CULL_PUSH as usize];
        push[..64].copy_from_slice(bytes_of(view_proj));
        push[64..80].copy_from_slice(bytes_of(&info));
        push[80..].copy_from_slice(bytes_of(&screen));
        rec.bind_compute_pipeline(&self.cull);
        rec.bind_compute_set(&self.cull_layout, self.cull_sets.get(0));
        rec.push_constants(&self.cull_layout, &push);
        rec.dispatch(
            "hiz culling",
            self.object_count.div_ceil(GROUP).max(1),
            1,
            1,
        )?;
        rec.memory_barrier(Access::ComputeReadWrite, Access::IndirectRead);
        r.write_timestamp()?;
        r.begin_target_rendering(phase == 1)?;
        r.bind_scene_geometry();
        let n = u64::from(self.object_count);
        let groups = self.groups.len() as u64;
        for (k, g) in self.groups.iter().enumerate() {
            r.bind_draw_class_of(g.object)?;
            let first = ((phase as u64 - 1) * n + u64::from(g.first_slot)) * COMMAND_BYTES;
            let count_offset = COUNTS_AT + ((phase as u64 - 1) * groups + k as u64) * 4;
            r.recorder_mut().draw_indexed_indirect_count(
                &self.draws,
                first,
                &self.counters,
                count_offset,
                g.size,
            );
        }
        if phase == 2 {
            // After everything the culling drew: blended objects (no depth writes), the heavy
            // ones tested against this depth as after the other algorithms' frames.
            r.record_blended()?;
        }
        let rec = r.recorder_mut();
        rec.end_rendering();
        if phase == 2 {
            r.copy_blended_tests();
        }
        r.write_timestamp()
    }

    /// Reads the frame's timestamps (it has completed): each pass's time, and the total.
    fn read_pass_times(&mut self, r: &Renderer) -> Result<f64> {
        let tick = r.context().info.timestamp_period_ns as f64 * 1e-6;
        // Written at the start and after each pass.
        let mut t = [0u64; 6];
        for (i, v) in t.iter_mut().enumerate() {
            *v = r.timestamp(i as u32)?.unwrap_or(0);
        }
        for k in 0..5 {
            self.last_pass_ms[k] = t[k + 1].saturating_sub(t[k]) as f64 * tick;
        }
        Ok(t[5].saturating_sub(t[0]) as f64 * tick)
    }

    /// Device time of each pass of the last frame, in the order of [`PASSES`] (timestamps
    /// between passes; on lavapipe the device is the CPU).
    pub fn last_pass_ms(&self) -> [f64; 5] {
        self.last_pass_ms
    }

    /// Reads each group's draws in both phases of the last frame (it has completed) into
    /// `group_counts`, and returns the triangles they drew.
    fn read_counters(&mut self) -> Result<u64> {
        let bytes = self
            .counters
            .mapped()
            .ok_or_else(|| Error::Alloc("hiz counters are not mapped".into()))?;
        let word = |i| {
            word_at(bytes, i).ok_or_else(|| Error::Alloc("hiz counters buffer is too short".into()))
        };
        let first = (COUNTS_AT / 4) as usize;
        for (k, count) in self.group_counts.iter_mut().enumerate() {
            *count = word(first + k)?;
        }
        Ok(u64::from(word(0)?) + u64::from(word(1)?))
    }

    /// Objects drawn by phase 1 (visible last frame) and phase 2 (newly visible) in the last
    /// frame, as the GPU counted them.
    pub fn last_phase_objects(&self) -> [u32; 2] {
        self.last_phases
    }

    /// Builds the pyramid from `r`'s depth buffer as it is now (one submission, waited for).
    /// For tests and inspection; frames build their own.
    pub fn build_pyramid(&mut self, r: &mut Renderer) -> Result<()> {
        let pyramid = &mut self.pyramid;
        r.run_one_shot(|rec, depth| pyramid.record_build(rec, depth))
    }

    /// Number of pyramid levels.
    pub fn pyramid_levels(&self) -> u32 {
        self.pyramid.image.levels()
    }

    /// The valid region of pyramid level `level` (the image is padded to powers of two).
    pub fn pyramid_level_size(&self, level: u32) -> (u32, u32) {
        self.pyramid.valid[level as usize]
    }

    /// Reads the valid region of pyramid level `level` back (row by row).
    pub fn read_pyramid_level(&mut self, r: &mut Renderer, level: u32) -> Result<Vec<f32>> {
        let (w, h) = self.pyramid_level_size(level);
        let stride = self.pyramid.image.level_size(level).0;
        let (oneshot, rec) = r.one_shot_parts();
        let texels = self.pyramid.image.read_level(oneshot, rec, level)?;
        Ok((0..h)
            .flat_map(|y| (0..w).map(move |x| (y * stride + x) as usize))
            .map(|i| texels[i])
            .collect())
    }
}

/// The objects of one [`DrawClass`](super::DrawClass): in each phase their draw commands fill
/// `size` slots from `first_slot` of that phase's stretch of the command buffer.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Group {
    first_slot: u32,
    size: u32,
    /// One object of the group (what it binds, the whole group binds).
    object: u32,
}

impl Group {
    /// The groups of `ranges` in the order their classes first appear, and each object's group.
    fn of(ranges: &[super::DrawRange]) -> (Vec<Group>, Vec<u32>) {
        let mut index = std::collections::HashMap::new();
        let mut groups: Vec<Group> = Vec::new();
        let group_of: Vec<u32> = ranges
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let k = *index.entry(r.class).or_insert_with(|| {
                    groups.push(Group {
                        first_slot: 0,
                        size: 0,
                        object: i as u32,
                    });
                    groups.len() as u32 - 1
                });
                groups[k as usize].size += 1;
                k
            })
            .collect();
        let mut next = 0;
        for g in &mut groups {
            g.first_slot = next;
            next += g.size;
        }
        (groups, group_of)
    }
}

impl Drop for HizCuller {
    fn drop(&mut self) {
        // Nothing may be in flight when the buffers, sets and pyramid are destroyed.
        let _ = self.ctx.wait_idle();
    }
}

/// Names of the passes of a frame, in order ([`HizCuller::last_pass_ms`]).
pub const PASSES: [&str; 5] = [
    "phase-1 cull",
    "phase-1 draw",
    "pyramid",
    "phase-2 cull",
    "phase-2 draw",
];

/// Checks the features and limits the culler relies on for `objects` objects.
fn check_device(ctx: &GpuContext, objects: u32) -> Result<()> {
    let i = &ctx.info;
    let mut missing = Vec::new();
    if !i.optional.draw_indirect_count {
        missing.push("drawIndirectCount".to_string());
    }
    if !i.optional.multi_draw_indirect {
        missing.push("multiDrawIndirect".to_string());
    }
    if !i.optional.draw_indirect_first_instance {
        missing.push("drawIndirectFirstInstance".to_string());
    }
    if !i.optional.depth_sampled {
        missing.push("SAMPLED_IMAGE on D32_SFLOAT".to_string());
    }
    if !i.optional.r32f_storage {
        missing.push("STORAGE_IMAGE and SAMPLED_IMAGE on R32_SFLOAT".to_string());
    }
    if objects > i.max_draw_indirect_count {
        missing.push(format!(
            "maxDrawIndirectCount >= {objects} (device: {})",
            i.max_draw_indirect_count
        ));
    }
    if objects.div_ceil(GROUP) > i.max_compute_work_group_count[0]
        || i.max_compute_work_group_size[0] < GROUP
        || i.max_compute_work_group_invocations < GROUP
    {
        missing.push(format!(
            "{} workgroups of {GROUP} (device: maxComputeWorkGroupCount[0] {})",
            objects.div_ceil(GROUP),
            i.max_compute_work_group_count[0]
        ));
    }
    let largest = (objects as u64 * BOUNDS_BYTES).max(2 * objects as u64 * COMMAND_BYTES);
    if largest > i.max_storage_buffer_range as u64 {
        missing.push(format!(
            "maxStorageBufferRange >= {largest} (device: {})",
            i.max_storage_buffer_range
        ));
    }
    if missing.is_empty() {
        Ok(())
    } else {
        Err(Error::Unsupported {
            feature: format!("hiz: {}", missing.join(", ")),
        })
    }
}

/// Names `walk`, `render` and `view` accept: the [`culling::ALGORITHMS`] and `hiz`.
pub fn algorithm_names() -> Vec<&'static str> {
    let mut names = culling::ALGORITHMS.to_vec();
    names.push("hiz");
    names
}

/// Checks an algorithm name (and its parameters) without a renderer.
pub fn check_algorithm(name: &str, params: &ChcppParams) -> Result<()> {
    let _ = params;
    if name == "hiz" {
        return Ok(());
    }
    if let Some((alg, mode)) = name.split_once('@') {
        culling::Latency::parse(mode)?;
        if culling::has_latency_modes(alg) {
            return Ok(());
        }
    }
    culling::check_name(name).map_err(|_| {
        Error::Input(format!(
            "unknown algorithm \"{name}\" (known: {})",
            algorithm_names().join(", ")
        ))
    })
}

/// A culling algorithm by name: a CPU traversal ([`Culler`]) or the GPU-driven [`HizCuller`].
pub enum FrameAlgorithm {
    /// One of the query-based (or reference) algorithms.
    Culler(Box<dyn Culler>),
    /// Two-phase Hi-Z.
    Hiz(Box<HizCuller>),
}

impl FrameAlgorithm {
    /// Creates `name` for `renderer` (`hiz` needs its scene and target; `nohc` and `pvs` what
    /// `setup` holds for them).
    pub fn create(name: &str, setup: &culling::CullerSetup, renderer: &Renderer) -> Result<Self> {
        if name == "hiz" {
            let hiz = HizCuller::new(renderer, HizParams::default())?;
            return Ok(FrameAlgorithm::Hiz(Box::new(hiz)));
        }
        check_algorithm(name, &setup.params)?;
        Ok(FrameAlgorithm::Culler(culling::create_named(name, setup)?))
    }

    /// The algorithm's name.
    pub fn name(&self) -> &str {
        match self {
            FrameAlgorithm::Culler(c) => c.name(),
            FrameAlgorithm::Hiz(_) => "hiz",
        }
    }

    /// Whether it needs the exact visible set (the oracle).
    pub fn needs_exact_visibility(&self) -> bool {
        match self {
            FrameAlgorithm::Culler(c) => c.needs_exact_visibility(),
            FrameAlgorithm::Hiz(_) => false,
        }
    }

    /// Whether it needs the objects whose own box shows against the exact depth (the box
    /// oracle), which [`Renderer::render_frame_given`] finds with a pass of its own.
    pub fn needs_box_visibility(&self) -> bool {
        match self {
            FrameAlgorithm::Culler(c) => c.needs_box_visibility(),
            FrameAlgorithm::Hiz(_) => false,
        }
    }

    /// Renders one frame.
    pub fn render_frame(
        &mut self,
        r: &mut Renderer,
        bvh: &ObjectBvh,
        camera: &Camera,
        frame: u64,
    ) -> Result<FrameResult> {
        self.render_frame_given(r, bvh, camera, frame, None)
    }

    /// Renders one frame, with the camera's exact visible set when it is known
    /// ([`Renderer::render_frame_given`]).
    pub fn render_frame_given(
        &mut self,
        r: &mut Renderer,
        bvh: &ObjectBvh,
        camera: &Camera,
        frame: u64,
        exact: Option<&[u32]>,
    ) -> Result<FrameResult> {
        match self {
            FrameAlgorithm::Culler(c) => {
                r.render_frame_given(c.as_mut(), bvh, camera, frame, exact)
            }
            FrameAlgorithm::Hiz(h) => h.render_frame(r, camera),
        }
    }

    /// Makes the frames report what they drew, for [`FrameAlgorithm::check`] (the renderer's
    /// recorder logs CPU-recorded draws; hiz reads its GPU-generated draws back).
    pub fn log_drawn_objects(&mut self, r: &mut Renderer, on: bool) -> Result<()> {
        match self {
            FrameAlgorithm::Culler(_) => {
                r.log_drawn_objects(on);
                Ok(())
            }
            FrameAlgorithm::Hiz(h) => h.log_drawn_objects(on),
        }
    }

    /// Counts the draws of `movers` as the frames' mover draws (see
    /// [`Renderer::count_mover_draws`]); hiz draws on the GPU, so it reads its draws back to
    /// count them (the copy of `walk --check`).
    pub fn count_mover_draws(
        &mut self,
        r: &mut Renderer,
        movers: std::ops::Range<u32>,
    ) -> Result<()> {
        if let FrameAlgorithm::Hiz(h) = self {
            if !movers.is_empty() && h.readback.is_none() {
                h.log_drawn_objects(true)?;
            }
        }
        r.count_mover_draws(movers);
        Ok(())
    }

    /// What the last frame missed against `pixels` of the exact ID pass (see
    /// [`Renderer::object_pixels`]); needs [`FrameAlgorithm::log_drawn_objects`].
    pub fn check(&self, r: &Renderer, pixels: &[u32]) -> super::Check {
        match self {
            FrameAlgorithm::Culler(_) => r.check_drawn(pixels),
            FrameAlgorithm::Hiz(h) => Renderer::check_objects(h.drawn_objects(), pixels),
        }
    }

    /// Forgets temporal state.
    pub fn reset(&mut self) -> Result<()> {
        match self {
            FrameAlgorithm::Culler(c) => {
                c.reset();
                Ok(())
            }
            FrameAlgorithm::Hiz(h) => h.reset(),
        }
    }
}
