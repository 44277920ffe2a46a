//! One photo on the GPU: every plane uploaded once, as f32, into one buffer; every
//! tile's kernel (a Gaussian's six numbers, else its taps) and the blend windows and
//! shrinkage tables into another, once; the tiles solved batch after batch (their
//! kernels made and transformed, the edge taper, every HQS step and the blend all
//! recorded without a host round trip); one readback of all planes. The large buffers
//! stay with the deblurrer from photo to photo, grown when a photo needs more.

use super::super::TileGrid;
use super::kernels::TileKernel;
use super::{
    FftParams, GpuDeblurrer, GpuError, MAX_LINE, Params, SHORT_LINE, Solve, StepParams, WORKGROUP,
    entry,
};
use crate::job::JobContext;
use crate::plane::Plane;
use crate::timings::{Stage, Timings};
use wgpu::util::DeviceExt;

/// The tile buffers of one batch (28 bytes a block pixel) stay under this, so a large
/// photo runs in several batches instead of asking for gigabytes.
const BATCH_BYTES: u64 = 1 << 30;

/// One plane of a photo: its pixels, its grid and each tile's kernel (row-major over
/// the grid).
pub(crate) struct PlaneJob<'a> {
    pub plane: &'a Plane,
    pub grid: TileGrid,
    pub kernels: Vec<TileKernel<'a>>,
}

/// The buffers a photo runs in, kept from photo to photo.
#[derive(Default)]
pub(super) struct Kept {
    planes: Option<wgpu::Buffer>,
    output: Option<wgpu::Buffer>,
    staging: Option<wgpu::Buffer>,
    est_a: Option<wgpu::Buffer>,
    est_b: Option<wgpu::Buffer>,
    num: Option<wgpu::Buffer>,
    den: Option<wgpu::Buffer>,
    aux: Option<wgpu::Buffer>,
    kinfo: Option<wgpu::Buffer>,
}

/// `slot`'s buffer when it holds at least `bytes`, else a new one of `bytes` in it.
fn kept<'k>(
    device: &wgpu::Device,
    slot: &'k mut Option<wgpu::Buffer>,
    label: &str,
    bytes: u64,
    usage: wgpu::BufferUsages,
) -> &'k wgpu::Buffer {
    let bytes = bytes.max(16).next_multiple_of(wgpu::COPY_BUFFER_ALIGNMENT);
    if slot.as_ref().is_some_and(|b| b.size() < bytes) {
        *slot = None;
    }
    slot.get_or_insert_with(|| {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: bytes,
            usage,
            mapped_at_creation: false,
        })
    })
}

/// Where each plane's pieces lie in the shared buffers.
struct Layout {
    /// Per plane: its first pixel in the planes and output buffers.
    plane0: Vec<usize>,
    /// Per plane: its first tile (kernel entry).
    tile0: Vec<usize>,
    /// Per plane: where its x and y windows start in `aux`.
    wins: Vec<(usize, usize)>,
    /// Per HQS step: its uniform values.
    steps: Vec<StepParams>,
    /// Per plane: tiles per batch.
    per_batch: Vec<usize>,
    /// The largest batch, in block pixels.
    batch_px: u64,
    pixels: usize,
    /// `aux`'s contents: kernels, windows, tables.
    aux: Vec<f32>,
    /// How many of `aux`'s first values are the kernels.
    kernel_len: usize,
    /// Per tile: (offset of its kernel in `aux`, its side; [`MADE_GAUSSIAN`] or
    /// [`MADE_SHAPE`] for numbers the device makes the taps of).
    kinfo: Vec<u32>,
}

/// A tile's side in `kinfo` that says its kernel is a Gaussian's numbers.
const MADE_GAUSSIAN: u32 = 0;
/// … a shape's numbers (`deblur.wgsl`'s `MADE_SHAPE`).
const MADE_SHAPE: u32 = u32::MAX;

impl Layout {
    fn of(jobs: &[PlaneJob<'_>], solve: &Solve, max_buffer: u64) -> Result<Self, GpuError> {
        let (mut aux, mut kinfo) = (Vec::new(), Vec::new());
        // Each shape model's components once, first, so their offsets are small.
        let mut components: Vec<(*const Vec<f64>, usize)> = Vec::new();
        for k in jobs.iter().flat_map(|j| &j.kernels) {
            if let TileKernel::Shape(t) = k
                && !components.iter().any(|c| c.0 == t.components.as_ptr())
            {
                components.push((t.components.as_ptr(), aux.len()));
                aux.extend(t.components.iter().flatten().map(|&v| v as f32));
            }
        }
        for k in jobs.iter().flat_map(|j| &j.kernels) {
            match k {
                TileKernel::Taps(k) => {
                    kinfo.extend([aux.len() as u32, k.size as u32]);
                    aux.extend(k.data.iter().map(|&v| v as f32));
                }
                TileKernel::Gaussian(g) => {
                    kinfo.extend([aux.len() as u32, MADE_GAUSSIAN]);
                    aux.extend(g.packed());
                }
                TileKernel::Shape(t) => {
                    let at = components
                        .iter()
                        .find(|c| c.0 == t.components.as_ptr())
                        .map_or(0, |c| c.1);
                    kinfo.extend([aux.len() as u32, MADE_SHAPE]);
                    aux.extend(t.packed(at));
                }
            }
        }
        let kernel_len = aux.len();
        let mut wins = Vec::new();
        let (mut plane0, mut tile0, mut per_batch) = (Vec::new(), Vec::new(), Vec::new());
        let (mut pixels, mut tiles, mut batch_px) = (0, 0, 0u64);
        for j in jobs {
            let g = &j.grid;
            let (bw, bh) = (g.x.block, g.y.block);
            if bw > MAX_LINE || bh > MAX_LINE {
                return Err(GpuError::Block {
                    width: bw,
                    height: bh,
                });
            }
            let block_px = (bw * bh) as u64;
            if 8 * block_px > max_buffer {
                return Err(GpuError::Block {
                    width: bw,
                    height: bh,
                });
            }
            let n = ((max_buffer / (8 * block_px)).min(BATCH_BYTES / (28 * block_px)) as usize)
                .clamp(1, g.tiles());
            per_batch.push(n);
            batch_px = batch_px.max(n as u64 * block_px);
            let wx = aux.len();
            aux.extend((0..g.x.count).flat_map(|t| g.x.window(t)).map(|v| v as f32));
            let wy = aux.len();
            aux.extend((0..g.y.count).flat_map(|t| g.y.window(t)).map(|v| v as f32));
            wins.push((wx, wy));
            plane0.push(pixels);
            tile0.push(tiles);
            pixels += j.plane.width * j.plane.height;
            tiles += g.tiles();
        }
        if 4 * pixels as u64 > max_buffer {
            let p = jobs
                .iter()
                .map(|j| j.plane)
                .max_by_key(|p| p.width * p.height);
            return Err(GpuError::Plane {
                width: p.map_or(0, |p| p.width),
                height: p.map_or(0, |p| p.height),
            });
        }
        let steps = solve
            .betas()
            .iter()
            .map(|&beta| {
                let (range, inv_step, values) =
                    super::super::solve::shrink_table(beta, solve.alpha());
                let s = StepParams {
                    beta: beta as f32,
                    range: range as f32,
                    inv_step: inv_step as f32,
                    last: (values.len() - 1) as f32,
                    table: aux.len() as u32,
                    pad: [0; 3],
                };
                aux.extend(values.iter().map(|&v| v as f32));
                s
            })
            .collect();
        Ok(Self {
            plane0,
            tile0,
            wins,
            steps,
            per_batch,
            batch_px,
            pixels,
            aux,
            kernel_len,
            kinfo,
        })
    }
}

/// The photo's buffers, borrowed from [`Kept`] for its run.
struct Buffers<'k> {
    planes: &'k wgpu::Buffer,
    output: &'k wgpu::Buffer,
    staging: &'k wgpu::Buffer,
    est_a: &'k wgpu::Buffer,
    est_b: &'k wgpu::Buffer,
    num: &'k wgpu::Buffer,
    den: &'k wgpu::Buffer,
    aux: &'k wgpu::Buffer,
    kinfo: &'k wgpu::Buffer,
}

/// The bind groups of one batch: the main stages' (estimate in a, or in b) and the
/// FFTs' of each buffer they transform (rows then columns, forward then inverse).
struct BatchGroups {
    ab: wgpu::BindGroup,
    ba: wgpu::BindGroup,
    tiles: u32,
    rows: u32,
}

/// One plane's FFT bind groups: for `est_a`, `est_b` and `num`, [forward, inverse] ×
/// [rows, columns].
struct FftGroups {
    a: [[wgpu::BindGroup; 2]; 2],
    b: [[wgpu::BindGroup; 2]; 2],
    num: [[wgpu::BindGroup; 2]; 2],
}

impl GpuDeblurrer {
    /// Deblurs the planes of one photo (at most as many as one buffer holds): upload,
    /// the passes of every batch of every plane, one readback.
    pub(super) fn run_photo(
        &self,
        jobs: &[PlaneJob<'_>],
        solve: &Solve,
        kept_buffers: &mut Kept,
        job: &JobContext,
    ) -> Result<Vec<Plane>, super::super::DeblurError> {
        let limits = self.device.limits();
        let max_buffer = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let upload = Timings::start(job.timings());
        let layout = Layout::of(jobs, solve, max_buffer)?;
        let bufs = self.buffers(kept_buffers, &layout);
        self.queue
            .write_buffer(bufs.aux, 0, bytemuck::cast_slice(&layout.aux));
        self.queue
            .write_buffer(bufs.kinfo, 0, bytemuck::cast_slice(&layout.kinfo));
        for (j, &p0) in jobs.iter().zip(&layout.plane0) {
            self.queue.write_buffer(
                bufs.planes,
                4 * p0 as u64,
                bytemuck::cast_slice(&j.plane.data),
            );
        }
        if let Some(t) = job.timings() {
            let kernels = 4 * (layout.kernel_len + layout.kinfo.len()) as u64;
            let all = 4 * (layout.pixels + layout.aux.len() + layout.kinfo.len()) as u64;
            t.add_upload(all, kernels);
        }
        let steps: Vec<wgpu::BindGroup> = layout.steps.iter().map(|s| self.step_group(s)).collect();
        let no_step = self.step_group(&bytemuck::Zeroable::zeroed());
        Timings::stop(job.timings(), Stage::Upload, upload);
        let passes = Timings::start(job.timings());
        let total: usize = jobs.iter().map(|j| j.grid.tiles()).sum();
        let mut done = 0;
        let bytes = 4 * layout.pixels as u64;
        let mut enc = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("deblur photo"),
            });
        enc.clear_buffer(bufs.output, 0, Some(bytes));
        for (p, j) in jobs.iter().enumerate() {
            job.check()?;
            let ffts = self.fft_groups(&bufs, &j.grid);
            let mut first = 0;
            while first < j.grid.tiles() {
                let n = layout.per_batch[p].min(j.grid.tiles() - first);
                let batch = self.batch_groups(&bufs, &layout, j, p, first, n, solve);
                self.record_batch(&mut enc, &j.grid, &batch, &ffts, &steps, &no_step, solve);
                first += n;
            }
            // A plane per submission: the device starts on it while the next is recorded.
            let next = self
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("deblur photo"),
                });
            self.queue
                .submit([std::mem::replace(&mut enc, next).finish()]);
            done += j.grid.tiles();
            job.report("deblur", done, total);
        }
        enc.copy_buffer_to_buffer(bufs.output, 0, bufs.staging, 0, bytes);
        self.queue.submit([enc.finish()]);
        if passes.is_some() {
            // Timed, the passes are waited for here so the readback is its own.
            self.device
                .poll(wgpu::PollType::wait_indefinitely())
                .map_err(|e| GpuError::Failed(e.to_string()))?;
        }
        Timings::stop(job.timings(), Stage::Gpu, passes);
        let started = Timings::start(job.timings());
        let data = self.read_back(bufs.staging, bytes)?;
        let planes = jobs
            .iter()
            .zip(&layout.plane0)
            .map(|(j, &p0)| Plane {
                width: j.plane.width,
                height: j.plane.height,
                data: data[p0..p0 + j.plane.width * j.plane.height].to_vec(),
            })
            .collect();
        Timings::stop(job.timings(), Stage::Readback, started);
        Ok(planes)
    }

    /// The kept buffers, grown to what `layout` needs.
    fn buffers<'k>(&self, k: &'k mut Kept, layout: &Layout) -> Buffers<'k> {
        use wgpu::BufferUsages as U;
        let d = &self.device;
        let plane_bytes = 4 * layout.pixels as u64;
        let batch = layout.batch_px;
        let rw = U::STORAGE;
        Buffers {
            planes: kept(d, &mut k.planes, "planes", plane_bytes, rw | U::COPY_DST),
            output: kept(
                d,
                &mut k.output,
                "deblurred planes",
                plane_bytes,
                rw | U::COPY_SRC | U::COPY_DST,
            ),
            staging: kept(
                d,
                &mut k.staging,
                "read back",
                plane_bytes,
                U::MAP_READ | U::COPY_DST,
            ),
            est_a: kept(d, &mut k.est_a, "estimate a", 8 * batch, rw),
            est_b: kept(d, &mut k.est_b, "estimate b", 8 * batch, rw),
            num: kept(d, &mut k.num, "numerator", 8 * batch, rw),
            den: kept(d, &mut k.den, "denominator", 4 * batch, rw),
            aux: kept(
                d,
                &mut k.aux,
                "kernels, windows and tables",
                4 * layout.aux.len() as u64,
                rw | U::COPY_DST,
            ),
            kinfo: kept(
                d,
                &mut k.kinfo,
                "kernel offsets",
                4 * layout.kinfo.len() as u64,
                rw | U::COPY_DST,
            ),
        }
    }

    fn step_group(&self, s: &StepParams) -> wgpu::BindGroup {
        let b = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("step"),
                contents: bytemuck::bytes_of(s),
                usage: wgpu::BufferUsages::UNIFORM,
            });
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("step"),
            layout: &self.step_layout,
            entries: &[entry(0, &b)],
        })
    }

    /// The FFT bind groups of one plane's block size.
    fn fft_groups(&self, bufs: &Buffers<'_>, grid: &TileGrid) -> FftGroups {
        let device = &self.device;
        let (bw, bh) = (grid.x.block, grid.y.block);
        let params = |n: usize, elem: usize, line: usize, sign: f32, scale: f32| {
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
            [params(bw, 1, bw, -1.0, 1.0), params(bh, bw, 1, -1.0, 1.0)],
            [params(bw, 1, bw, 1.0, 1.0), params(bh, bw, 1, 1.0, inv_n)],
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
        let groups = |data: &wgpu::Buffer| -> [[wgpu::BindGroup; 2]; 2] {
            passes.each_ref().map(|dir| {
                [0, 1].map(|axis| {
                    device.create_bind_group(&wgpu::BindGroupDescriptor {
                        label: Some("fft"),
                        layout: &self.fft_layout,
                        entries: &[
                            entry(0, data),
                            entry(1, &dir[axis]),
                            entry(2, &line_roots[axis]),
                        ],
                    })
                })
            })
        };
        FftGroups {
            a: groups(bufs.est_a),
            b: groups(bufs.est_b),
            num: groups(bufs.num),
        }
    }

    /// The uniforms and main bind groups of tiles `first..first + tiles` of plane `p`.
    #[allow(clippy::too_many_arguments)]
    fn batch_groups(
        &self,
        bufs: &Buffers<'_>,
        layout: &Layout,
        j: &PlaneJob<'_>,
        p: usize,
        first: usize,
        tiles: usize,
        solve: &Solve,
    ) -> BatchGroups {
        let g = &j.grid;
        let (w, h) = (j.plane.width, j.plane.height);
        let (ty0, ty1) = (first / g.x.count, (first + tiles - 1) / g.x.count);
        let row0 = g.y.window_start(ty0).max(0) as usize;
        let row1 = ((g.y.window_start(ty1) + g.y.window_len() as isize).max(0) as usize).min(h);
        let (lambda, alpha, nsr) = solve.constants();
        let params = Params {
            bw: g.x.block as u32,
            bh: g.y.block as u32,
            tiles: tiles as u32,
            tile0: first as u32,
            count_x: g.x.count as u32,
            count_y: g.y.count as u32,
            plane_w: w as u32,
            plane_h: h as u32,
            step_x: g.x.step as u32,
            step_y: g.y.step as u32,
            ramp_x: g.x.ramp as u32,
            ramp_y: g.y.ramp as u32,
            margin_x: g.x.margin_before as u32,
            margin_y: g.y.margin_before as u32,
            win_x: g.x.window_len() as u32,
            win_y: g.y.window_len() as u32,
            taper: g.taper as u32,
            row0: row0 as u32,
            rows: row1.saturating_sub(row0) as u32,
            wins_y: layout.wins[p].1 as u32,
            wins_x: layout.wins[p].0 as u32,
            lambda,
            alpha,
            nsr,
            plane0: layout.plane0[p] as u32,
            kinfo0: (layout.tile0[p] + first) as u32,
            pad: [0; 2],
        };
        let params = self
            .device
            .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("params"),
                contents: bytemuck::bytes_of(&params),
                usage: wgpu::BufferUsages::UNIFORM,
            });
        let group = |src: &wgpu::Buffer, dst: &wgpu::Buffer| {
            self.device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("deblur"),
                layout: &self.main_layout,
                entries: &[
                    entry(0, &params),
                    entry(1, bufs.planes),
                    entry(2, src),
                    entry(3, dst),
                    entry(4, bufs.num),
                    entry(5, bufs.den),
                    entry(6, bufs.kinfo),
                    entry(7, bufs.aux),
                    entry(8, bufs.output),
                ],
            })
        };
        BatchGroups {
            ab: group(bufs.est_a, bufs.est_b),
            ba: group(bufs.est_b, bufs.est_a),
            tiles: tiles as u32,
            rows: row1.saturating_sub(row0) as u32,
        }
    }

    /// Records one batch: the Gaussian kernels' sums, blocks and kernels loaded, the
    /// kernels' spectra, the edge taper, the solver's steps and the blend into the
    /// output.
    #[allow(clippy::too_many_arguments)]
    fn record_batch(
        &self,
        enc: &mut wgpu::CommandEncoder,
        grid: &TileGrid,
        b: &BatchGroups,
        ffts: &FftGroups,
        steps: &[wgpu::BindGroup],
        no_step: &wgpu::BindGroup,
        solve: &Solve,
    ) {
        let (bw, bh) = (grid.x.block as u32, grid.y.block as u32);
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("deblur batch"),
            timestamp_writes: None,
        });
        let t = b.tiles;
        let blocks_2d = [bw.div_ceil(16), bh.div_ceil(16), t];
        let elements = [(bw * bh).div_ceil(WORKGROUP), t, 1];
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
        let fft_for = |n: u32| {
            if n as usize <= SHORT_LINE {
                &self.fft_short
            } else {
                &self.fft_long
            }
        };
        let fft =
            |pass: &mut wgpu::ComputePass<'_>, g: &[[wgpu::BindGroup; 2]; 2], inverse: bool| {
                let g = &g[usize::from(inverse)];
                pass.set_pipeline(fft_for(bw));
                pass.set_bind_group(0, &g[0], &[]);
                pass.dispatch_workgroups(bh, t, 1);
                pass.set_pipeline(fft_for(bh));
                pass.set_bind_group(0, &g[1], &[]);
                pass.dispatch_workgroups(bw, t, 1);
            };
        let s = &self.stages;
        stage(&mut pass, &s.kernel_sum, &b.ab, no_step, [t, 1, 1]);
        stage(&mut pass, &s.load, &b.ab, no_step, blocks_2d);
        fft(&mut pass, &ffts.num, false);
        if grid.taper > 0 {
            fft(&mut pass, &ffts.b, false);
            stage(&mut pass, &s.blur, &b.ab, no_step, elements);
            fft(&mut pass, &ffts.b, true);
            stage(&mut pass, &s.taper, &b.ab, no_step, blocks_2d);
        }
        fft(&mut pass, &ffts.b, false);
        // Which group reads the estimate at the end.
        let last = match solve {
            Solve::Wiener { .. } => {
                stage(&mut pass, &s.wiener, &b.ab, no_step, elements);
                fft(&mut pass, &ffts.b, true);
                &b.ba
            }
            Solve::Hqs { .. } => {
                stage(&mut pass, &s.prepare, &b.ab, no_step, elements);
                let mut estimate_in_a = true;
                for step in steps {
                    let (group, groups) = if estimate_in_a {
                        (&b.ab, &ffts.b)
                    } else {
                        (&b.ba, &ffts.a)
                    };
                    stage(&mut pass, &s.divergence, group, step, blocks_2d);
                    fft(&mut pass, groups, false);
                    stage(&mut pass, &s.update, group, step, elements);
                    fft(&mut pass, groups, true);
                    estimate_in_a = !estimate_in_a;
                }
                if estimate_in_a { &b.ab } else { &b.ba }
            }
        };
        let width = (grid.x.len as u32).div_ceil(16);
        stage(
            &mut pass,
            &s.blend,
            last,
            no_step,
            [width, b.rows.div_ceil(16), 1],
        );
    }
}
