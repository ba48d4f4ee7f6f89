//! Descriptor sets: one pool sized for a few pipeline layouts, one set per layout, written once
//! at creation (so no set is ever updated while a command buffer uses it); and samplers.

use std::sync::Arc;

use ash::vk;

use super::memory::{Buffer, Image};
use super::pipelines::PipelineLayout;
use super::pyramid::MipImage;
use super::texture::Texture;
use super::GpuContext;
use crate::error::{Error, Result, VkContext};

/// A descriptor set allocated by [`DescriptorSets`], to bind with the recorder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DescriptorSet(pub(crate) vk::DescriptorSet);

/// What one binding of a set points at.
#[derive(Clone, Copy)]
pub enum Binding<'a> {
    /// A storage buffer (whole range).
    StorageBuffer(&'a Buffer),
    /// A storage image, accessed in GENERAL layout.
    StorageImage(&'a Image),
    /// A combined image sampler, sampled in SHADER_READ_ONLY_OPTIMAL layout.
    Sampled(&'a Image, &'a Sampler),
    /// One mip level of a [`MipImage`] as a storage image (GENERAL layout).
    StorageMip(&'a MipImage, u32),
    /// A combined image sampler over one level of a [`MipImage`] (`Some(level)`) or all of
    /// them (`None`), sampled in GENERAL layout.
    SampledMips(&'a MipImage, Option<u32>, &'a Sampler),
    /// A combined image sampler over all levels of a material [`Texture`]
    /// (SHADER_READ_ONLY_OPTIMAL layout).
    Texture(&'a Texture, &'a Sampler),
}

impl Binding<'_> {
    fn ty(&self) -> vk::DescriptorType {
        match self {
            Binding::StorageBuffer(_) => vk::DescriptorType::STORAGE_BUFFER,
            Binding::StorageImage(_) | Binding::StorageMip(..) => vk::DescriptorType::STORAGE_IMAGE,
            Binding::Sampled(..) | Binding::SampledMips(..) | Binding::Texture(..) => {
                vk::DescriptorType::COMBINED_IMAGE_SAMPLER
            }
        }
    }
}

/// A descriptor pool with one set per layout it was made for.
pub struct DescriptorSets {
    ctx: Arc<GpuContext>,
    pool: vk::DescriptorPool,
    sets: Vec<vk::DescriptorSet>,
}

impl DescriptorSets {
    /// Allocates one set per `(layout, bindings)` and writes `bindings[i]` to binding `i`;
    /// every binding of the layout must be given, with the type the layout declares.
    pub fn new(
        ctx: &Arc<GpuContext>,
        sets: &[(&PipelineLayout, &[Binding])],
    ) -> Result<DescriptorSets> {
        for (layout, bindings) in sets {
            check_bindings(layout, bindings)?;
            for b in bindings.iter() {
                if let Binding::StorageBuffer(buf) = b {
                    ctx.info
                        .check_storage_buffer("storage buffer binding", buf.size)?;
                }
            }
        }
        let mut me = DescriptorSets {
            ctx: ctx.clone(),
            pool: Self::create_pool(ctx, sets)?,
            sets: Vec::new(),
        };
        let layouts: Vec<_> = sets.iter().map(|(l, _)| l.set_layout).collect();
        let alloc = vk::DescriptorSetAllocateInfo::default()
            .descriptor_pool(me.pool)
            .set_layouts(&layouts);
        // SAFETY: the pool was sized for exactly these sets.
        me.sets = unsafe { ctx.device.allocate_descriptor_sets(&alloc) }
            .vk("vkAllocateDescriptorSets")?;
        for (i, (_, bindings)) in sets.iter().enumerate() {
            me.write(me.sets[i], bindings);
        }
        Ok(me)
    }

    fn create_pool(
        ctx: &GpuContext,
        sets: &[(&PipelineLayout, &[Binding])],
    ) -> Result<vk::DescriptorPool> {
        let mut sizes: Vec<vk::DescriptorPoolSize> = Vec::new();
        for b in sets.iter().flat_map(|(_, b)| b.iter()) {
            match sizes.iter_mut().find(|s| s.ty == b.ty()) {
                Some(s) => s.descriptor_count += 1,
                None => sizes.push(vk::DescriptorPoolSize {
                    ty: b.ty(),
                    descriptor_count: 1,
                }),
            }
        }
        let info = vk::DescriptorPoolCreateInfo::default()
            .max_sets(sets.len() as u32)
            .pool_sizes(&sizes);
        // SAFETY: valid device and create info.
        unsafe { ctx.device.create_descriptor_pool(&info, None) }.vk("vkCreateDescriptorPool")
    }

    fn write(&self, set: vk::DescriptorSet, bindings: &[Binding]) {
        let buffers: Vec<[vk::DescriptorBufferInfo; 1]> = bindings
            .iter()
            .map(|b| match b {
                Binding::StorageBuffer(buf) => [vk::DescriptorBufferInfo {
                    buffer: buf.handle,
                    offset: 0,
                    range: vk::WHOLE_SIZE,
                }],
                _ => [vk::DescriptorBufferInfo::default()],
            })
            .collect();
        let images: Vec<[vk::DescriptorImageInfo; 1]> = bindings
            .iter()
            .map(|b| match b {
                Binding::StorageImage(img) => [vk::DescriptorImageInfo {
                    sampler: vk::Sampler::null(),
                    image_view: img.view,
                    image_layout: vk::ImageLayout::GENERAL,
                }],
                Binding::Sampled(img, sampler) => [vk::DescriptorImageInfo {
                    sampler: sampler.handle,
                    image_view: img.view,
                    image_layout: vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL,
                }],
                Binding::StorageMip(img, level) => [vk::DescriptorImageInfo {
                    sampler: vk::Sampler::null(),
                    image_view: img.level_views[*level as usize],
                    image_layout: vk::ImageLayout::GENERAL,
                }],
                Binding::SampledMips(img, level, sampler) => [vk::DescriptorImageInfo {
                    sampler: sampler.handle,
                    image_view: match level {
                        Some(l) => img.level_views[*l as usize],
                        None => img.all_levels,
                    },
                    image_layout: vk::ImageLayout::GENERAL,
                }],
                Binding::Texture(tex, sampler) => [vk::DescriptorImageInfo {
                    sampler: sampler.handle,
                    image_view: tex.view,
                    image_layout: vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL,
                }],
                Binding::StorageBuffer(_) => [vk::DescriptorImageInfo::default()],
            })
            .collect();
        let writes: Vec<_> = bindings
            .iter()
            .enumerate()
            .map(|(i, b)| {
                let w = vk::WriteDescriptorSet::default()
                    .dst_set(set)
                    .dst_binding(i as u32)
                    .descriptor_type(b.ty());
                match b {
                    Binding::StorageBuffer(_) => w.buffer_info(&buffers[i]),
                    _ => w.image_info(&images[i]),
                }
            })
            .collect();
        // SAFETY: the set is new (not in use); buffers, views and samplers are valid.
        unsafe { self.ctx.device.update_descriptor_sets(&writes, &[]) };
    }

    /// The set made for the `index`-th layout.
    pub fn get(&self, index: usize) -> DescriptorSet {
        DescriptorSet(self.sets[index])
    }
}

fn check_bindings(layout: &PipelineLayout, bindings: &[Binding]) -> Result<()> {
    for b in bindings {
        let level = match b {
            Binding::StorageMip(img, l) | Binding::SampledMips(img, Some(l), _) => Some((img, l)),
            _ => None,
        };
        if let Some((img, &l)) = level.filter(|(img, &l)| l >= img.levels()) {
            return Err(Error::Input(format!(
                "mip level {l} bound, the image has {}",
                img.levels()
            )));
        }
    }
    let declared = layout.bindings();
    let matches = declared.len() == bindings.len()
        && declared.iter().zip(bindings).all(|(&t, b)| t == b.ty());
    if matches {
        Ok(())
    } else {
        Err(Error::Input(format!(
            "descriptor set bindings {:?} do not match the layout's {declared:?}",
            bindings.iter().map(|b| b.ty()).collect::<Vec<_>>()
        )))
    }
}

impl Drop for DescriptorSets {
    fn drop(&mut self) {
        // SAFETY: owners drop their sets after the work that used them has completed; the sets
        // are freed with the pool.
        unsafe { self.ctx.device.destroy_descriptor_pool(self.pool, None) };
    }
}

/// A sampler (destroyed on drop).
pub struct Sampler {
    ctx: Arc<GpuContext>,
    handle: vk::Sampler,
}

impl Sampler {
    /// Nearest filtering, no mipmaps, clamped to the edge (shadow-map lookups).
    pub fn nearest_clamp(ctx: &Arc<GpuContext>) -> Result<Sampler> {
        let info = vk::SamplerCreateInfo::default()
            .mag_filter(vk::Filter::NEAREST)
            .min_filter(vk::Filter::NEAREST)
            .mipmap_mode(vk::SamplerMipmapMode::NEAREST)
            .address_mode_u(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .address_mode_v(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .address_mode_w(vk::SamplerAddressMode::CLAMP_TO_EDGE)
            .max_lod(0.0);
        // SAFETY: valid device and create info.
        let handle = unsafe { ctx.device.create_sampler(&info, None) }.vk("vkCreateSampler")?;
        Ok(Sampler {
            ctx: ctx.clone(),
            handle,
        })
    }
}

impl Sampler {
    /// Takes ownership of a sampler created on `ctx`'s device.
    pub(crate) fn from_handle(ctx: &Arc<GpuContext>, handle: vk::Sampler) -> Sampler {
        Sampler {
            ctx: ctx.clone(),
            handle,
        }
    }
}

impl Drop for Sampler {
    fn drop(&mut self) {
        // SAFETY: owners drop samplers after the work that used them has completed.
        unsafe { self.ctx.device.destroy_sampler(self.handle, None) };
    }
}
