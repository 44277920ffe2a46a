//! The deblur on a GPU through wgpu compute shaders: the same tiles, kernels, edge
//! taper, solver and blend as the CPU path ([`super::deblur_channel_plane`]), in
//! single precision, on a batch of tiles at a time.
//!
//! The CPU path stays the reference and the fallback. A [`GpuDeblurrer`] wraps a wgpu
//! device: its own (the command line) or one lent by the caller (the studio lends the
//! device its window draws with, so the preview does not open a second one). One is
//! shared by the process ([`shared`]); [`Device`] says whether a deblur may use it.

use super::{
    DeblurError, DeblurOptions, KernelSource, Method, TileGrid, cropped, plane_kernel_at,
    plane_tile_grid,
};
use crate::job::JobContext;
use crate::plane::{ChannelPlane, Plane};
use crate::psf::Kernel;
use crate::timings::{Stage, Timings};
use rayon::prelude::*;
use std::sync::{Arc, Mutex, OnceLock};
use wgpu::util::DeviceExt;

/// Where a deblur runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Device {
    /// The CPU path (the reference).
    #[default]
    Cpu,
    /// The GPU, whatever adapter wgpu finds (a software one included); an error when
    /// there is none or it cannot run the shaders.
    Gpu,
    /// The GPU when a hardware adapter that can run the shaders is there, else the CPU:
    /// a software rasteriser is slower than the CPU path.
    Auto,
}

impl Device {
    #[must_use]
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "cpu" => Some(Self::Cpu),
            "gpu" => Some(Self::Gpu),
            "auto" => Some(Self::Auto),
            _ => None,
        }
    }

    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Cpu => "cpu",
            Self::Gpu => "gpu",
            Self::Auto => "auto",
        }
    }
}

#[derive(Clone, Debug, thiserror::Error)]
pub enum GpuError {
    #[error("no GPU adapter found")]
    NoAdapter,
    #[error("the only adapter is a software rasteriser ({0})")]
    Software(String),
    #[error("the adapter {name} cannot run the deblur shaders: {what}")]
    Unsupported { name: String, what: String },
    #[error("the GPU path has no {0}: it runs on the CPU")]
    Method(&'static str),
    #[error("the GPU device could not be opened: {0}")]
    Open(String),
    #[error("the GPU failed: {0}")]
    Failed(String),
    #[error(
        "{width} × {height} blocks are beyond the GPU path (lines of at most {MAX_LINE} points)"
    )]
    Block { width: usize, height: usize },
    #[error("a {width} × {height} plane is beyond this adapter's largest buffer")]
    Plane { width: usize, height: usize },
}

/// The longest FFT line one workgroup holds (`fft.wgsl`'s `MAX_N`).
pub const MAX_LINE: usize = 2048;
/// Invocations per workgroup the shaders use.
const WORKGROUP: u32 = 256;
/// Lines up to this long take the FFT with 64 invocations per workgroup.
const SHORT_LINE: usize = 512;
/// The tile buffers of one batch (four per pixel: 28 bytes) stay under this, so a
/// large photo runs in several batches instead of asking for gigabytes.
const BATCH_BYTES: u64 = 1 << 30;

/// What one adapter is, for messages.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AdapterName {
    pub name: String,
    pub backend: String,
    pub software: bool,
}

impl std::fmt::Display for AdapterName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} ({}", self.name, self.backend)?;
        if self.software {
            write!(f, ", software")?;
        }
        write!(f, ")")
    }
}

impl AdapterName {
    fn of(info: &wgpu::AdapterInfo) -> Self {
        Self {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend),
            software: info.device_type == wgpu::DeviceType::Cpu,
        }
    }
}

/// A wgpu device with the deblur's pipelines built.
pub struct GpuDeblurrer {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter: AdapterName,
    /// For lines of up to [`SHORT_LINE`] points (64 invocations), and longer (256).
    fft_short: wgpu::ComputePipeline,
    fft_long: wgpu::ComputePipeline,
    fft_layout: wgpu::BindGroupLayout,
    main_layout: wgpu::BindGroupLayout,
    step_layout: wgpu::BindGroupLayout,
    stages: Stages,
    /// One plane at a time: the device's memory holds one plane's batch.
    busy: Mutex<()>,
}

struct Stages {
    load: wgpu::ComputePipeline,
    blur: wgpu::ComputePipeline,
    taper: wgpu::ComputePipeline,
    prepare: wgpu::ComputePipeline,
    wiener: wgpu::ComputePipeline,
    divergence: wgpu::ComputePipeline,
    update: wgpu::ComputePipeline,
    blend: wgpu::ComputePipeline,
}

/// What the shaders need of a device beyond WebGPU's defaults: nothing, but an adapter
/// that offers less (a downlevel one) is refused with the reason.
fn check_limits(limits: &wgpu::Limits, name: &AdapterName) -> Result<(), GpuError> {
    let need = [
        (
            limits.max_compute_workgroup_storage_size >= 16384,
            "16 KiB of workgroup memory",
        ),
        (
            limits.max_compute_invocations_per_workgroup >= WORKGROUP,
            "256 invocations per workgroup",
        ),
        (
            limits.max_storage_buffers_per_shader_stage >= 8,
            "8 storage buffers per stage",
        ),
        (limits.max_bind_groups >= 2, "2 bind groups"),
    ];
    match need.iter().find(|(ok, _)| !ok) {
        Some((_, what)) => Err(GpuError::Unsupported {
            name: name.to_string(),
            what: (*what).to_owned(),
        }),
        None => Ok(()),
    }
}

fn storage(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn uniform(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

impl GpuDeblurrer {
    /// Opens a device of its own on the adapter wgpu prefers (`WGPU_BACKEND` and the
    /// other wgpu variables are honoured), asking for all the adapter's limits so a
    /// large plane fits one buffer.
    ///
    /// # Errors
    /// No adapter, one that cannot run the shaders, or a device that fails to open.
    pub fn open() -> Result<Self, GpuError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            ..Default::default()
        }))
        .map_err(|_| GpuError::NoAdapter)?;
        let name = AdapterName::of(&adapter.get_info());
        let limits = adapter.limits();
        check_limits(&limits, &name)?;
        if !adapter
            .get_downlevel_capabilities()
            .flags
            .contains(wgpu::DownlevelFlags::COMPUTE_SHADERS)
        {
            return Err(GpuError::Unsupported {
                name: name.to_string(),
                what: "compute shaders".into(),
            });
        }
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("lensblur deblur"),
            required_features: wgpu::Features::empty(),
            required_limits: limits,
            ..Default::default()
        }))
        .map_err(|e| GpuError::Open(e.to_string()))?;
        Self::with_device(device, queue, &adapter.get_info())
    }

    /// Builds the pipelines on a device the caller owns (the studio's window device).
    ///
    /// # Errors
    /// A device whose limits the shaders exceed, or shaders that fail to build on it.
    pub fn with_device(
        device: wgpu::Device,
        queue: wgpu::Queue,
        info: &wgpu::AdapterInfo,
    ) -> Result<Self, GpuError> {
        let adapter = AdapterName::of(info);
        check_limits(&device.limits(), &adapter)?;
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let fft_module = device.create_shader_module(wgpu::include_wgsl!("gpu/fft.wgsl"));
        let main_module = device.create_shader_module(wgpu::include_wgsl!("gpu/deblur.wgsl"));
        let fft_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("fft"),
            entries: &[storage(0, false), uniform(1), storage(2, true)],
        });
        let main_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("deblur"),
            entries: &[
                uniform(0),
                storage(1, true),
                storage(2, false),
                storage(3, false),
                storage(4, false),
                storage(5, false),
                storage(6, true),
                storage(7, true),
                storage(8, false),
            ],
        });
        let step_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("deblur step"),
            entries: &[uniform(0)],
        });
        let fft_pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("fft"),
            bind_group_layouts: &[Some(&fft_layout)],
            immediate_size: 0,
        });
        let main_pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("deblur"),
            bind_group_layouts: &[Some(&main_layout), Some(&step_layout)],
            immediate_size: 0,
        });
        let pipeline = |layout: &wgpu::PipelineLayout,
                        module: &wgpu::ShaderModule,
                        entry: &str,
                        constants: &[(&str, f64)]| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(layout),
                module,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants,
                    ..Default::default()
                },
                cache: None,
            })
        };
        let main = |entry| pipeline(&main_pipeline_layout, &main_module, entry, &[]);
        let fft_short = pipeline(&fft_pipeline_layout, &fft_module, "fft", &[("WG", 64.0)]);
        let fft_long = pipeline(&fft_pipeline_layout, &fft_module, "fft", &[]);
        let stages = Stages {
            load: main("load"),
            blur: main("blur"),
            taper: main("taper"),
            prepare: main("prepare"),
            wiener: main("wiener"),
            divergence: main("divergence"),
            update: main("update"),
            blend: main("blend"),
        };
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Unsupported {
                name: adapter.to_string(),
                what: e.to_string(),
            });
        }
        Ok(Self {
            device,
            queue,
            adapter,
            fft_short,
            fft_long,
            fft_layout,
            main_layout,
            step_layout,
            stages,
            busy: Mutex::new(()),
        })
    }

    /// The adapter this deblurrer runs on.
    #[must_use]
    pub fn adapter(&self) -> &AdapterName {
        &self.adapter
    }

    /// Deblurs one channel plane of a capture with the kernels of `source`: the GPU twin
    /// of [`super::deblur_channel_plane`] (the same grid and kernels).
    ///
    /// # Errors
    /// A source that cannot supply a kernel, cancellation, a method the GPU path lacks
    /// (IRLS), blocks or planes beyond the device, or a device failure.
    pub fn deblur_channel_plane(
        &self,
        cp: &ChannelPlane,
        (sensor_width, sensor_height): (usize, usize),
        source: &dyn KernelSource,
        opts: &DeblurOptions,
        job: &JobContext,
    ) -> Result<Plane, DeblurError> {
        let solve = Solve::of(&opts.method)?;
        let started = Timings::start(job.timings());
        let grid = plane_tile_grid(cp, sensor_width, sensor_height, source, opts)?;
        Timings::stop(job.timings(), Stage::Grid, started);
        let started = Timings::start(job.timings());
        let max_kernel = 2 * grid.x.margin_before.min(grid.y.margin_before) + 1;
        let total = grid.tiles();
        let kernels: Vec<Kernel> = (0..total)
            .into_par_iter()
            .map(|g| -> Result<Kernel, DeblurError> {
                let (tx, ty) = (g % grid.x.count, g / grid.x.count);
                let k = plane_kernel_at(
                    cp,
                    sensor_width,
                    sensor_height,
                    source,
                    grid.x.centre(tx),
                    grid.y.centre(ty),
                )?;
                Ok(cropped(k, max_kernel).resampled(1))
            })
            .collect::<Result<_, _>>()?;
        Timings::stop(job.timings(), Stage::Kernels, started);
        if let Some(t) = job.timings() {
            t.add_tiles(total);
        }
        job.check()?;
        let _busy = self
            .busy
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let scope_oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out = self.run(&cp.plane, &grid, &kernels, &solve, job);
        let validation = pollster::block_on(scope.pop());
        let oom = pollster::block_on(scope_oom.pop());
        if let Some(e) = validation.or(oom) {
            return Err(GpuError::Failed(e.to_string()).into());
        }
        out
    }

    #[allow(clippy::too_many_lines)]
    fn run(
        &self,
        plane: &Plane,
        grid: &TileGrid,
        kernels: &[Kernel],
        solve: &Solve,
        job: &JobContext,
    ) -> Result<Plane, DeblurError> {
        let (w, h) = (plane.width, plane.height);
        let (bw, bh) = (grid.x.block, grid.y.block);
        if bw > MAX_LINE || bh > MAX_LINE {
            return Err(GpuError::Block {
                width: bw,
                height: bh,
            }
            .into());
        }
        let limits = self.device.limits();
        let max_buffer = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let plane_bytes = (w * h * 4) as u64;
        if plane_bytes > max_buffer {
            return Err(GpuError::Plane {
                width: w,
                height: h,
            }
            .into());
        }
        let block_px = (bw * bh) as u64;
        let total = grid.tiles();
        let per_batch = ((max_buffer / (8 * block_px)).min(BATCH_BYTES / (28 * block_px)) as usize)
            .clamp(1, total);
        if 8 * block_px > max_buffer {
            return Err(GpuError::Block {
                width: bw,
                height: bh,
            }
            .into());
        }
        let upload = Timings::start(job.timings());
        let device = &self.device;
        let buffer = |label: &str, bytes: u64, usage: wgpu::BufferUsages| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: bytes.max(16),
                usage,
                mapped_at_creation: false,
            })
        };
        let rw = wgpu::BufferUsages::STORAGE;
        let input = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("plane"),
            contents: bytemuck::cast_slice(&plane.data),
            usage: rw,
        });
        let output = buffer(
            "deblurred plane",
            plane_bytes,
            rw | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST,
        );
        let batch_px = per_batch as u64 * block_px;
        let est_a = buffer("estimate a", 8 * batch_px, rw);
        let est_b = buffer("estimate b", 8 * batch_px, rw);
        let num = buffer("numerator", 8 * batch_px, rw);
        let den = buffer("denominator", 4 * batch_px, rw);
        // The windows after the largest batch's kernels in `aux`.
        let windows: Vec<f32> = (0..grid.x.count)
            .flat_map(|t| grid.x.window(t))
            .chain((0..grid.y.count).flat_map(|t| grid.y.window(t)))
            .map(|v| v as f32)
            .collect();
        let kernel_room = kernels
            .chunks(per_batch)
            .map(|b| b.iter().map(|k| k.data.len()).sum::<usize>())
            .max()
            .unwrap_or(0);
        let kinfo = buffer(
            "kernel offsets",
            8 * per_batch as u64,
            rw | wgpu::BufferUsages::COPY_DST,
        );
        let params = buffer(
            "params",
            std::mem::size_of::<Params>() as u64,
            wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        );
        let fft_params = |n: usize, elem: usize, line: usize, sign: f32, scale: f32| {
            let p = FftParams {
                n: n as u32,
                elem_stride: elem as u32,
                line_stride: line as u32,
                tile_stride: (bw * bh) as u32,
                sign,
                scale,
                pad: [0; 2],
            };
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("fft params"),
                contents: bytemuck::bytes_of(&p),
                usage: wgpu::BufferUsages::UNIFORM,
            })
        };
        let inv_n = 1.0 / (bw * bh) as f32;
        // Rows then columns, forward and inverse; the inverse scales on its last pass.
        let passes = [
            [
                fft_params(bw, 1, bw, -1.0, 1.0),
                fft_params(bh, bw, 1, -1.0, 1.0),
            ],
            [
                fft_params(bw, 1, bw, 1.0, 1.0),
                fft_params(bh, bw, 1, 1.0, inv_n),
            ],
        ];
        let roots = |n: usize| {
            let table: Vec<[f32; 2]> = (0..n)
                .map(|k| {
                    let t = -std::f64::consts::TAU * k as f64 / n as f64;
                    [t.cos() as f32, t.sin() as f32]
                })
                .collect();
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("fft roots"),
                contents: bytemuck::cast_slice(&table),
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        // Rows are bw long, columns bh.
        let line_roots = [roots(bw), roots(bh)];
        let fft_group = |data: &wgpu::Buffer, p: &wgpu::Buffer, r: &wgpu::Buffer| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("fft"),
                layout: &self.fft_layout,
                entries: &[entry(0, data), entry(1, p), entry(2, r)],
            })
        };
        let fft_groups = |data: &wgpu::Buffer| -> [[wgpu::BindGroup; 2]; 2] {
            passes.each_ref().map(|dir| {
                [
                    fft_group(data, &dir[0], &line_roots[0]),
                    fft_group(data, &dir[1], &line_roots[1]),
                ]
            })
        };
        let (fft_a, fft_b, fft_num) = (fft_groups(&est_a), fft_groups(&est_b), fft_groups(&num));
        let step_group = |s: &StepParams| {
            let b = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("step"),
                contents: bytemuck::bytes_of(s),
                usage: wgpu::BufferUsages::UNIFORM,
            });
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("step"),
                layout: &self.step_layout,
                entries: &[entry(0, &b)],
            })
        };
        let tables_at = kernel_room + windows.len();
        let mut tables: Vec<f32> = Vec::new();
        let steps: Vec<wgpu::BindGroup> = solve
            .betas()
            .iter()
            .map(|&beta| {
                let (range, inv_step, values) = super::solve::shrink_table(beta, solve.alpha());
                let s = StepParams {
                    beta: beta as f32,
                    range: range as f32,
                    inv_step: inv_step as f32,
                    last: (values.len() - 1) as f32,
                    table: (tables_at + tables.len()) as u32,
                    pad: [0; 3],
                };
                tables.extend(values.iter().map(|&v| v as f32));
                step_group(&s)
            })
            .collect();
        // Group 1 for the stages that take no step.
        let no_step = step_group(&bytemuck::Zeroable::zeroed());
        let aux = buffer(
            "kernels, windows and tables",
            4 * (tables_at + tables.len()) as u64,
            rw | wgpu::BufferUsages::COPY_DST,
        );
        self.queue
            .write_buffer(&aux, 4 * kernel_room as u64, bytemuck::cast_slice(&windows));
        self.queue
            .write_buffer(&aux, 4 * tables_at as u64, bytemuck::cast_slice(&tables));
        let main_group = |src: &wgpu::Buffer, dst: &wgpu::Buffer| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("deblur"),
                layout: &self.main_layout,
                entries: &[
                    entry(0, &params),
                    entry(1, &input),
                    entry(2, src),
                    entry(3, dst),
                    entry(4, &num),
                    entry(5, &den),
                    entry(6, &kinfo),
                    entry(7, &aux),
                    entry(8, &output),
                ],
            })
        };
        // a → b: estimate in a, the block being transformed in b; and the reverse.
        let ab = main_group(&est_a, &est_b);
        let ba = main_group(&est_b, &est_a);
        let (lambda, alpha, nsr) = solve.constants();
        let mut done_tiles = 0;
        let mut first = 0;
        Timings::stop(job.timings(), Stage::Upload, upload);
        let passes = Timings::start(job.timings());
        while first < total {
            job.check()?;
            let tiles = per_batch.min(total - first);
            let batch = &kernels[first..first + tiles];
            let mut info = Vec::with_capacity(2 * tiles);
            let mut taps = Vec::with_capacity(kernel_room);
            for k in batch {
                info.extend([taps.len() as u32, k.size as u32]);
                taps.extend(k.data.iter().map(|&v| v as f32));
            }
            self.queue
                .write_buffer(&kinfo, 0, bytemuck::cast_slice(&info));
            self.queue
                .write_buffer(&aux, 0, bytemuck::cast_slice(&taps));
            let (ty0, ty1) = (first / grid.x.count, (first + tiles - 1) / grid.x.count);
            let row0 = grid.y.window_start(ty0).max(0) as usize;
            let row1 =
                ((grid.y.window_start(ty1) + grid.y.window_len() as isize).max(0) as usize).min(h);
            let p = Params {
                bw: bw as u32,
                bh: bh as u32,
                tiles: tiles as u32,
                tile0: first as u32,
                count_x: grid.x.count as u32,
                count_y: grid.y.count as u32,
                plane_w: w as u32,
                plane_h: h as u32,
                step_x: grid.x.step as u32,
                step_y: grid.y.step as u32,
                ramp_x: grid.x.ramp as u32,
                ramp_y: grid.y.ramp as u32,
                margin_x: grid.x.margin_before as u32,
                margin_y: grid.y.margin_before as u32,
                win_x: grid.x.window_len() as u32,
                win_y: grid.y.window_len() as u32,
                taper: grid.taper as u32,
                row0: row0 as u32,
                rows: row1.saturating_sub(row0) as u32,
                wins_y: (kernel_room + grid.x.count * grid.x.window_len()) as u32,
                wins_x: kernel_room as u32,
                lambda,
                alpha,
                nsr,
            };
            self.queue.write_buffer(&params, 0, bytemuck::bytes_of(&p));
            let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("deblur batch"),
            });
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("deblur batch"),
                    timestamp_writes: None,
                });
                let t = tiles as u32;
                let blocks_2d = [(bw as u32).div_ceil(16), (bh as u32).div_ceil(16), t];
                let elements = [(block_px as u32).div_ceil(WORKGROUP), t, 1];
                let stage = |pass: &mut wgpu::ComputePass<'_>,
                             pipeline: &wgpu::ComputePipeline,
                             group: &wgpu::BindGroup,
                             step: &wgpu::BindGroup,
                             size: [u32; 3]| {
                    pass.set_pipeline(pipeline);
                    pass.set_bind_group(0, group, &[]);
                    pass.set_bind_group(1, step, &[]);
                    pass.dispatch_workgroups(size[0], size[1], size[2]);
                };
                let fft = |pass: &mut wgpu::ComputePass<'_>,
                           groups: &[[wgpu::BindGroup; 2]; 2],
                           inverse: bool| {
                    let g = &groups[usize::from(inverse)];
                    let fft_for = |n: usize| {
                        if n <= SHORT_LINE {
                            &self.fft_short
                        } else {
                            &self.fft_long
                        }
                    };
                    pass.set_pipeline(fft_for(bw));
                    pass.set_bind_group(0, &g[0], &[]);
                    pass.dispatch_workgroups(bh as u32, t, 1);
                    pass.set_pipeline(fft_for(bh));
                    pass.set_bind_group(0, &g[1], &[]);
                    pass.dispatch_workgroups(bw as u32, t, 1);
                };
                let s = &self.stages;
                stage(&mut pass, &s.load, &ab, &no_step, blocks_2d);
                fft(&mut pass, &fft_num, false);
                if grid.taper > 0 {
                    fft(&mut pass, &fft_b, false);
                    stage(&mut pass, &s.blur, &ab, &no_step, elements);
                    fft(&mut pass, &fft_b, true);
                    stage(&mut pass, &s.taper, &ab, &no_step, blocks_2d);
                }
                fft(&mut pass, &fft_b, false);
                // Which buffer holds the estimate at the end.
                let last = match solve {
                    Solve::Wiener { .. } => {
                        stage(&mut pass, &s.wiener, &ab, &no_step, elements);
                        fft(&mut pass, &fft_b, true);
                        &ba
                    }
                    Solve::Hqs { .. } => {
                        stage(&mut pass, &s.prepare, &ab, &no_step, elements);
                        let mut estimate_in_a = true;
                        for step in &steps {
                            let (group, groups) = if estimate_in_a {
                                (&ab, &fft_b)
                            } else {
                                (&ba, &fft_a)
                            };
                            stage(&mut pass, &s.divergence, group, step, blocks_2d);
                            fft(&mut pass, groups, false);
                            stage(&mut pass, &s.update, group, step, elements);
                            fft(&mut pass, groups, true);
                            estimate_in_a = !estimate_in_a;
                        }
                        if estimate_in_a { &ab } else { &ba }
                    }
                };
                let rows = row1.saturating_sub(row0) as u32;
                stage(
                    &mut pass,
                    &s.blend,
                    last,
                    &no_step,
                    [(w as u32).div_ceil(16), rows.div_ceil(16), 1],
                );
            }
            self.queue.submit([enc.finish()]);
            done_tiles += tiles;
            first += tiles;
            job.report("deblur", done_tiles, total);
        }
        if passes.is_some() {
            // Timed, the passes are waited for here so the readback is its own.
            self.device
                .poll(wgpu::PollType::wait_indefinitely())
                .map_err(|e| GpuError::Failed(e.to_string()))?;
        }
        Timings::stop(job.timings(), Stage::Gpu, passes);
        let started = Timings::start(job.timings());
        let data = self.read_back(&output, plane_bytes)?;
        Timings::stop(job.timings(), Stage::Readback, started);
        Ok(Plane {
            width: w,
            height: h,
            data,
        })
    }

    fn read_back(&self, output: &wgpu::Buffer, bytes: u64) -> Result<Vec<f32>, DeblurError> {
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read back"),
            size: bytes.max(16),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("read back"),
            });
        enc.copy_buffer_to_buffer(output, 0, &staging, 0, bytes);
        self.queue.submit([enc.finish()]);
        let slice = staging.slice(..bytes);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Failed(e.to_string()))?;
        match rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(GpuError::Failed(e.to_string()).into()),
            Err(e) => return Err(GpuError::Failed(e.to_string()).into()),
        }
        let data = {
            let view = slice
                .get_mapped_range()
                .map_err(|e| GpuError::Failed(e.to_string()))?;
            bytemuck::pod_collect_to_vec::<u8, f32>(&view)
        };
        staging.unmap();
        Ok(data)
    }
}

fn entry(binding: u32, buffer: &wgpu::Buffer) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: buffer.as_entire_binding(),
    }
}

/// The solver as the shaders run it.
enum Solve {
    Hqs {
        lambda: f64,
        alpha: f64,
        betas: Vec<f64>,
    },
    Wiener {
        nsr: f64,
    },
}

impl Solve {
    fn of(method: &Method) -> Result<Self, GpuError> {
        match method {
            Method::Hqs(p) => {
                // The CPU solver's continuation, step for step.
                let mut betas = Vec::new();
                let mut beta = p.beta_start;
                while beta <= p.beta_max * (1.0 + 1e-9) {
                    betas.push(beta);
                    beta *= p.beta_rate;
                }
                Ok(Self::Hqs {
                    lambda: p.lambda,
                    alpha: p.alpha,
                    betas,
                })
            }
            Method::Wiener(p) => Ok(Self::Wiener { nsr: p.nsr }),
            Method::Irls(_) => Err(GpuError::Method("IRLS")),
        }
    }

    fn betas(&self) -> &[f64] {
        match self {
            Self::Hqs { betas, .. } => betas,
            Self::Wiener { .. } => &[],
        }
    }

    fn alpha(&self) -> f64 {
        match self {
            Self::Hqs { alpha, .. } => *alpha,
            Self::Wiener { .. } => 0.0,
        }
    }

    fn constants(&self) -> (f32, f32, f32) {
        match self {
            Self::Hqs { lambda, alpha, .. } => (*lambda as f32, *alpha as f32, 0.0),
            Self::Wiener { nsr } => (0.0, 0.0, *nsr as f32),
        }
    }
}

/// `deblur.wgsl`'s `Params`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    bw: u32,
    bh: u32,
    tiles: u32,
    tile0: u32,
    count_x: u32,
    count_y: u32,
    plane_w: u32,
    plane_h: u32,
    step_x: u32,
    step_y: u32,
    ramp_x: u32,
    ramp_y: u32,
    margin_x: u32,
    margin_y: u32,
    win_x: u32,
    win_y: u32,
    taper: u32,
    row0: u32,
    rows: u32,
    wins_y: u32,
    wins_x: u32,
    lambda: f32,
    alpha: f32,
    nsr: f32,
}

/// `deblur.wgsl`'s `Step`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct StepParams {
    beta: f32,
    range: f32,
    inv_step: f32,
    last: f32,
    table: u32,
    pad: [u32; 3],
}

/// `fft.wgsl`'s `FftParams`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FftParams {
    n: u32,
    elem_stride: u32,
    line_stride: u32,
    tile_stride: u32,
    sign: f32,
    scale: f32,
    pad: [u32; 2],
}

/// The process's GPU deblurrer: the device lent by [`lend`] if one was, else one opened
/// on first use. Opening is tried once; its failure is remembered, so a machine
/// without a GPU says so once and goes on on the CPU.
static SHARED: OnceLock<Result<Arc<GpuDeblurrer>, GpuError>> = OnceLock::new();

/// Lends the process a device to deblur on (the studio lends its window's), before
/// anything has asked for [`shared`].
///
/// # Errors
/// When the device cannot run the shaders (remembered: later deblurs fall back), or when
/// the process already has its deblurrer.
pub fn lend(
    device: wgpu::Device,
    queue: wgpu::Queue,
    info: &wgpu::AdapterInfo,
) -> Result<Arc<GpuDeblurrer>, GpuError> {
    let mut made = None;
    let r = SHARED.get_or_init(|| {
        let r = GpuDeblurrer::with_device(device, queue, info).map(Arc::new);
        made = Some(());
        r
    });
    match (made, r) {
        (Some(()), r) => r.clone(),
        (None, _) => Err(GpuError::Open(
            "this process already deblurs on another device".into(),
        )),
    }
}

/// The process's deblurrer, opened on first use.
///
/// # Errors
/// Why there is none (remembered from the first try).
pub fn shared() -> Result<Arc<GpuDeblurrer>, GpuError> {
    SHARED
        .get_or_init(|| GpuDeblurrer::open().map(Arc::new))
        .clone()
}

/// Where a deblur with `device` runs: the deblurrer for the GPU, `Ok(None)` for the
/// CPU. `Auto` takes a hardware adapter only, and the CPU for a method the GPU path
/// lacks.
///
/// # Errors
/// `Gpu` asked with no usable adapter, or with a method the GPU path lacks.
pub fn resolve(device: Device, method: &Method) -> Result<Option<Arc<GpuDeblurrer>>, GpuError> {
    match device {
        Device::Cpu => Ok(None),
        Device::Gpu => {
            Solve::of(method)?;
            shared().map(Some)
        }
        Device::Auto => Ok(match (Solve::of(method), shared()) {
            (Ok(_), Ok(g)) if !g.adapter.software => Some(g),
            _ => None,
        }),
    }
}

/// One line on where a deblur with `device` runs, and why when it is not where asked.
#[must_use]
pub fn describe(device: Device, method: &Method) -> String {
    match (device, resolve(device, method)) {
        (Device::Cpu, _) => "CPU".into(),
        (_, Ok(Some(g))) => format!("GPU: {}", g.adapter),
        (Device::Auto, Ok(None)) => match (Solve::of(method), shared()) {
            (Err(e), _) | (_, Err(e)) => format!("CPU ({e})"),
            (_, Ok(g)) => format!(
                "CPU (the only adapter, {}, is a software rasteriser)",
                g.adapter.name
            ),
        },
        (_, Ok(None)) => "CPU".into(),
        (_, Err(e)) => format!("none ({e})"),
    }
}
