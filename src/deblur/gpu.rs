//! The deblur on a GPU through wgpu compute shaders: the same tiles, kernels, edge
//! taper, solver and blend as the CPU path ([`super::deblur_channel_plane`]), in
//! single precision, a photo at a time ([`photo`]: every plane uploaded once, batches
//! of tiles solved without a host round trip, one readback).
//!
//! The CPU path stays the reference and the fallback. A [`GpuDeblurrer`] wraps a wgpu
//! device: its own (the command line) or one lent by the caller (the studio lends the
//! device its window draws with, so the preview does not open a second one). One is
//! shared by the process ([`shared`]); [`Device`] says whether a deblur may use it.

mod kernels;
mod photo;

use super::{DeblurError, DeblurOptions, KernelSource, Method};
use crate::job::JobContext;
use crate::plane::{Capture, Plane};
use crate::timings::{Stage, Timings};
use kernels::TileKernel;
use photo::PlaneJob;
use rayon::prelude::*;
use std::sync::{Arc, Mutex, OnceLock};

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
    /// One photo at a time, in the buffers kept from the last one.
    kept: Mutex<photo::Kept>,
}

struct Stages {
    kernel_sum: wgpu::ComputePipeline,
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
            kernel_sum: main("kernel_sum"),
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
            kept: Mutex::new(photo::Kept::default()),
        })
    }

    /// The adapter this deblurrer runs on.
    #[must_use]
    pub fn adapter(&self) -> &AdapterName {
        &self.adapter
    }

    /// Deblurs every plane of a capture with the kernels of `source`: the GPU twin of
    /// the CPU path (the same grids and kernels), one photo's planes at a time.
    ///
    /// # Errors
    /// A source that cannot supply a kernel, cancellation, a method the GPU path lacks
    /// (IRLS), blocks or planes beyond the device, or a device failure.
    pub fn deblur_planes(
        &self,
        cap: &Capture,
        source: &dyn KernelSource,
        opts: &DeblurOptions,
        job: &JobContext,
    ) -> Result<Vec<Plane>, DeblurError> {
        let solve = Solve::of(&opts.method)?;
        let jobs = plane_jobs(cap, source, opts, job)?;
        job.check()?;
        let mut kept = self
            .kept
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let scope_oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        // All planes in one run when one buffer holds them, else one plane at a time.
        let limits = self.device.limits();
        let max_buffer = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let pixels: usize = jobs.iter().map(|j| j.plane.data.len()).sum();
        let size = if 4 * pixels as u64 <= max_buffer {
            jobs.len().max(1)
        } else {
            1
        };
        let mut out = Vec::with_capacity(jobs.len());
        let mut failed = None;
        for group in jobs.chunks(size) {
            match self.run_photo(group, &solve, &mut kept, job) {
                Ok(planes) => out.extend(planes),
                Err(e) => {
                    failed = Some(e);
                    break;
                }
            }
        }
        let validation = pollster::block_on(scope.pop());
        let oom = pollster::block_on(scope_oom.pop());
        if let Some(e) = validation.or(oom) {
            // What the device holds after a failure is not to be trusted again.
            *kept = photo::Kept::default();
            return Err(GpuError::Failed(e.to_string()).into());
        }
        match failed {
            Some(e) => Err(e),
            None => Ok(out),
        }
    }

    /// The first `bytes` of `staging` (the passes that fill it submitted).
    fn read_back(&self, staging: &wgpu::Buffer, bytes: u64) -> Result<Vec<f32>, DeblurError> {
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

/// Every plane's grid and every tile's kernel (a Gaussian's few numbers, or 1× taps):
/// the grids one per plane, the kernels of all planes' tiles in one parallel pass.
fn plane_jobs<'c>(
    cap: &'c Capture,
    source: &'c dyn KernelSource,
    opts: &DeblurOptions,
    job: &JobContext,
) -> Result<Vec<PlaneJob<'c>>, DeblurError> {
    let (w, h) = (cap.width, cap.height);
    let grids = super::tile_grids(cap, source, opts, job)?;
    let tiles: Vec<(usize, usize)> = grids
        .iter()
        .enumerate()
        .flat_map(|(p, g)| (0..g.tiles()).map(move |t| (p, t)))
        .collect();
    if let Some(t) = job.timings() {
        t.add_tiles(tiles.len());
    }
    let kernels: Vec<TileKernel> = tiles
        .into_par_iter()
        .map(|(p, t)| -> Result<TileKernel, DeblurError> {
            let started = Timings::start(job.timings());
            let g = &grids[p];
            let max_kernel = 2 * g.x.margin_before.min(g.y.margin_before) + 1;
            let (tx, ty) = (t % g.x.count, t / g.x.count);
            let centre = [g.x.centre(tx), g.y.centre(ty)];
            let k = kernels::tile_kernel(&cap.planes[p], (w, h), source, centre, max_kernel)?;
            Timings::stop(job.timings(), Stage::Kernels, started);
            Ok(k)
        })
        .collect::<Result<_, _>>()?;
    let mut kernels = kernels.into_iter();
    Ok(cap
        .planes
        .iter()
        .zip(grids)
        .map(|(cp, grid)| PlaneJob {
            plane: &cp.plane,
            grid,
            kernels: kernels.by_ref().take(grid.tiles()).collect(),
        })
        .collect())
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
    /// This plane's first pixel in the planes and output buffers.
    plane0: u32,
    /// The batch's first tile in the kernel offsets.
    kinfo0: u32,
    pad: [u32; 2],
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
