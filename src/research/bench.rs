//! `eyekey bench`: figures for the transport operator, the sparse kernels, the solver and a whole encode,
//! printed and written to a Markdown file ([`run`]). Not a test: nothing here asserts on time.

use eyekey_core::physics::transport::TransportCache;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use super::table_header;
use crate::cli::BenchArgs;
use eyekey_core::encoding::objectives::{noise_decoy, MultiplexObjective, Term};
use eyekey_core::encoding::pipeline::{self, EncodeOptions, JobSpec};
use eyekey_core::encoding::solver::{minimise, minimise_spg, Objective, SolverOptions};
use eyekey_core::physics::display::DisplayGeometry;
use eyekey_core::physics::observer::{Observer, Optics};
use eyekey_core::physics::profile::VisionProfile;
use eyekey_core::physics::transport::{EyePosition, ProductMethod, SubRaySequence, TransportMatrix, TransportOptions};

/// Peak resident memory of this process so far, bytes (Linux `VmHWM`; 0 elsewhere).
pub fn peak_memory_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find(|l| l.starts_with("VmHWM:")).and_then(|l| {
                l.split_whitespace()
                    .nth(1)
                    .and_then(|kb| kb.parse::<u64>().ok())
                    .map(|kb| kb * 1024)
            })
        })
        .unwrap_or(0)
}

/// CPU time this process has used, every thread's, user and system (getrusage), in seconds.
pub fn cpu_seconds() -> f64 {
    // SAFETY: getrusage writes the struct it is given and nothing else.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return f64::NAN;
    }
    let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    secs(usage.ru_utime) + secs(usage.ru_stime)
}

/// The process's CPU time sampled every 10 ms from a thread of its own while some work runs, to tell how many
/// cores a phase of that work kept busy ([`Self::busy`]).
struct CpuTrace {
    start: Instant,
    samples: std::sync::Arc<std::sync::Mutex<Vec<(f64, f64)>>>,
    stop: std::sync::Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl CpuTrace {
    fn start() -> Self {
        let start = Instant::now();
        let samples = std::sync::Arc::new(std::sync::Mutex::new(vec![(0.0, cpu_seconds())]));
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let thread = {
            let (samples, stop) = (samples.clone(), stop.clone());
            std::thread::spawn(move || {
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    std::thread::sleep(std::time::Duration::from_millis(10));
                    let at = start.elapsed().as_secs_f64();
                    samples
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .push((at, cpu_seconds()));
                }
            })
        };
        Self {
            start,
            samples,
            stop,
            thread: Some(thread),
        }
    }

    /// Stops sampling (one last sample now).
    fn finish(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        let at = self.start.elapsed().as_secs_f64();
        self.samples
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push((at, cpu_seconds()));
    }

    /// The cores kept busy on average between `from` and `to` seconds after the start: CPU time over wall time,
    /// from the samples nearest inside the window.
    fn busy(&self, from: f64, to: f64) -> f64 {
        let samples = self.samples.lock().unwrap_or_else(|e| e.into_inner());
        let inside: Vec<&(f64, f64)> = samples.iter().filter(|(t, _)| *t >= from && *t <= to).collect();
        match (inside.first(), inside.last()) {
            (Some(a), Some(b)) if b.0 > a.0 => (b.1 - a.1) / (b.0 - a.0),
            _ => f64::NAN,
        }
    }
}

/// Streaming read bandwidth of this machine: a parallel sum over a 512 MiB f32 array, best of 5, GB/s.
pub fn streaming_read_gbps() -> f64 {
    let n = 128 << 20;
    let data: Vec<f32> = (0..n).into_par_iter().map(|i| (i % 7) as f32).collect();
    let mut best = f64::INFINITY;
    let mut sink = 0.0f64;
    for _ in 0..5 {
        let t = Instant::now();
        // Sixteen independent lanes per chunk so the sum vectorises and memory, not the adder, is the limit.
        sink += data
            .par_chunks(1 << 16)
            .map(|c| {
                let mut acc = [0f32; 16];
                for block in c.chunks_exact(16) {
                    for (a, v) in acc.iter_mut().zip(block) {
                        *a += v;
                    }
                }
                acc.iter().map(|v| *v as f64).sum::<f64>()
            })
            .sum::<f64>();
        best = best.min(t.elapsed().as_secs_f64());
    }
    std::hint::black_box(sink);
    (n * 4) as f64 / best / 1e9
}

/// The best (shortest) wall time of `reps` runs of `f`, seconds.
fn time_best<F: FnMut()>(reps: usize, mut f: F) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..reps {
        let t = Instant::now();
        f();
        best = best.min(t.elapsed().as_secs_f64());
    }
    best
}

/// The benchmark's eye: a perfect eye with some defocus, coma and spherical aberration.
fn bench_wavefront() -> Result<eyekey_core::physics::zernike::ZernikeCoefficients> {
    accommodated_bench_wavefront(0.0)
}

/// The bench eye accommodated by `dioptres` (+ nearer), as an evaluation sweeps a person's focus.
fn accommodated_bench_wavefront(dioptres: f64) -> Result<eyekey_core::physics::zernike::ZernikeCoefficients> {
    let mut p = VisionProfile::perfect();
    p.zernike_um[4] = 0.3;
    p.zernike_um[7] = 0.15;
    p.zernike_um[12] = 0.1;
    let p = eyekey_core::physics::accommodation::Accommodation::accommodated(&p, dioptres);
    Ok(p.effective_wavefront()?)
}

/// Timings of one transport operator: its build and the forward and adjoint kernels, with their compulsory
/// memory traffic.
struct KernelTimes {
    /// Seconds to build T (best of 3).
    build: f64,
    /// Seconds for A·L (best of 20).
    forward: f64,
    /// Seconds for Aᵀ·y (best of 20).
    adjoint: f64,
    /// Bytes A·L must move: the matrix once, the input vector once, the output once.
    forward_bytes: f64,
    /// Bytes Aᵀ·y must move.
    adjoint_bytes: f64,
}

/// Builds the operator (best of 3; the first run also pays page faults) and times its kernels.
fn time_kernels(display: &DisplayGeometry, sub_rays: u32) -> Result<(TransportMatrix, KernelTimes)> {
    let w = bench_wavefront()?;
    let opts = TransportOptions {
        sub_rays,
        ..Default::default()
    };
    let mut t_matrix = None;
    let build = time_best(3, || {
        t_matrix = Some(TransportMatrix::build(display, &w, EyePosition::default(), &opts).expect("valid preset"))
    });
    let t = t_matrix.context("transport build")?;
    let n = display.n_bands();
    let coupling: Vec<[f32; 3]> = (0..n).map(|k| [0.3 + 0.1 * k as f32, 0.5, 0.2]).collect();
    let l: Vec<f32> = (0..t.n_samples() * n).map(|i| (i % 13) as f32 / 13.0).collect();
    let mut y = vec![0f32; t.n_pixels() * 3];
    let mut x = vec![0f32; t.n_samples() * n];
    let forward = time_best(20, || t.forward_lms(&l, &coupling, &mut y));
    let adjoint = time_best(20, || t.adjoint_lms(&y, &coupling, &mut x));
    // Compulsory traffic: the matrix (indptr, indices, values) once, the input vector once, the output once.
    let matrix_bytes = |m: &eyekey_core::physics::transport::CsrMatrix| (m.indptr.len() * 4 + m.nnz() * 8) as f64;
    let (t_fwd, t_adj) = t.sparse().context("a traced (geometric) operator is held as CSR")?;
    let times = KernelTimes {
        build,
        forward,
        adjoint,
        forward_bytes: matrix_bytes(t_fwd) + (l.len() * 4) as f64 + (y.len() * 4) as f64,
        adjoint_bytes: matrix_bytes(t_adj) + (y.len() * 4) as f64 + (x.len() * 4) as f64,
    };
    Ok((t, times))
}

/// Runs the transport/kernel benchmark on a display; returns Markdown lines.
pub fn transport_bench(display: &DisplayGeometry, sub_rays: u32) -> Result<String> {
    let bw = streaming_read_gbps();
    let (t, times) = time_kernels(display, sub_rays)?;
    transport_table(display, sub_rays, bw, &t, &times)
}

/// The transport benchmark's `| quantity | value |` table.
fn transport_table(
    display: &DisplayGeometry,
    sub_rays: u32,
    bw: f64,
    t: &TransportMatrix,
    times: &KernelTimes,
) -> Result<String> {
    let mut out = table_header(&["quantity", "value"]);
    let n = display.n_bands();
    let traced = t.stats.sub_rays_traced as f64;
    let build = times.build;
    let (fwd, adj) = (times.forward, times.adjoint);
    writeln!(
        out,
        "| display | {}×{} holes, {}×{} views, {} bands ({} unknowns) |",
        display.holes_x,
        display.holes_y,
        display.views_u,
        display.views_v,
        n,
        t.n_samples() * n
    )?;
    writeln!(out, "| sub-rays per sample (S) | {sub_rays} |")?;
    writeln!(out, "| rayon threads | {} |", rayon::current_num_threads())?;
    writeln!(
        out,
        "| streaming read bandwidth (parallel sum, 512 MiB) | {bw:.2} GB/s |"
    )?;
    writeln!(out, "| T build time | {:.3} s |", build)?;
    writeln!(out, "| sub-rays traced per second | {:.1} M/s |", traced / build / 1e6)?;
    writeln!(
        out,
        "| sub-rays entering the pupil | {:.1} % |",
        100.0 * t.stats.sub_rays_in_pupil as f64 / traced
    )?;
    writeln!(
        out,
        "| nnz(T) | {} ({:.1} MB for T and Tᵀ) |",
        t.nnz(),
        t.memory_bytes() as f64 / 1e6
    )?;
    writeln!(
        out,
        "| A·L (all {n} bands + coupling) | {:.2} ms, {:.2} GB/s effective = {:.0} % of streaming |",
        fwd * 1e3,
        times.forward_bytes / fwd / 1e9,
        100.0 * times.forward_bytes / fwd / 1e9 / bw
    )?;
    writeln!(
        out,
        "| Aᵀ·y | {:.2} ms, {:.2} GB/s effective = {:.0} % of streaming |",
        adj * 1e3,
        times.adjoint_bytes / adj / 1e9,
        100.0 * times.adjoint_bytes / adj / 1e9 / bw
    )?;
    writeln!(
        out,
        "| peak resident memory | {:.0} MB |",
        peak_memory_bytes() as f64 / 1e6
    )?;
    Ok(out)
}

/// One display's wave-optics figures: one person's per-band kernels built, and the products
/// S = Σ_n c_n T_n L_n and its adjoint, against the geometric CSR operator of the same display.
struct WaveFigures {
    name: String,
    display: DisplayGeometry,
    build: f64,
    /// Forward and adjoint, all bands, by stencils and by FFT.
    stencil: (f64, f64),
    fft: (f64, f64),
    /// What the operators chose.
    chosen: ProductMethod,
    /// The first FFT product's time, which computes the kernels' spectra.
    fft_first: f64,
    /// Bytes of the kernels' spectra, all bands.
    spectra_bytes: usize,
    /// Multiply-adds of one product, all bands.
    mads: usize,
    /// Bytes the stencils hold, all bands.
    bytes: usize,
    /// Bytes the same operators would take expanded as CSR (T and Tᵀ: index and value per entry, row pointers).
    csr_bytes: usize,
    /// Mean and largest kernel taps per view, over bands.
    taps: (f64, usize),
    geometric_forward: f64,
    geometric_adjoint: f64,
}

fn wave_figures(name: &str, sub_rays: u32) -> Result<WaveFigures> {
    use eyekey_core::physics::observer::{transports, Lens};
    let display = DisplayGeometry::preset(name)?;
    let w = bench_wavefront()?;
    let opts = TransportOptions {
        sub_rays,
        ..Default::default()
    };
    let lens = Lens::Eye {
        wavefront: &w,
        reference_nm: 555.0,
    };
    let cache = TransportCache::disabled();
    let mut built = None;
    let build = time_best(3, || {
        built = Some(transports(
            &display,
            lens,
            EyePosition::default(),
            &opts,
            Optics::Wave,
            &cache,
        ))
    });
    let ts = built.context("wave build")??;
    let n = display.n_bands();
    let coupling: Vec<[f32; 3]> = (0..n).map(|k| [0.3 + 0.1 * k as f32, 0.5, 0.2]).collect();
    let samples = ts[0].n_samples();
    let l: Vec<f32> = (0..samples * n).map(|i| (i % 13) as f32 / 13.0).collect();
    let mut y = vec![0f32; ts[0].n_pixels() * 3];
    let mut x = vec![0f32; samples * n];
    let chosen = ts[0]
        .product_method()
        .context("a wave operator at the design distance")?;
    let mut time_method = |method: ProductMethod| {
        let ts: Vec<_> = ts.iter().map(|t| t.with_product_method(method)).collect();
        let t0 = std::time::Instant::now();
        for (band, t) in ts.iter().enumerate() {
            t.forward_band_lms(None, &l, n, band, coupling[band], band > 0, &mut y);
        }
        let first = t0.elapsed().as_secs_f64();
        let forward = time_best(10, || {
            for (band, t) in ts.iter().enumerate() {
                t.forward_band_lms(None, &l, n, band, coupling[band], band > 0, &mut y);
            }
        });
        let adjoint = time_best(10, || {
            for (band, t) in ts.iter().enumerate() {
                t.adjoint_band_lms(None, &y, n, band, coupling[band], &mut x);
            }
        });
        let held: usize = ts.iter().map(|t| t.memory_bytes()).sum();
        (forward, adjoint, first, held)
    };
    let stencil = time_method(ProductMethod::Stencil);
    let fft = time_method(ProductMethod::Fft);
    let mads: usize = ts.iter().map(|t| t.nnz()).sum();
    let bytes: usize = ts.iter().map(|t| t.memory_bytes()).sum();
    let csr_bytes: usize = ts
        .iter()
        .map(|t| t.nnz() * 16 + (t.n_pixels() + t.n_samples() + 2) * 4)
        .sum();
    let views = (display.views_u * display.views_v) as usize;
    let taps = (
        mads as f64 / (ts.len() * samples) as f64,
        ts.iter()
            .flat_map(|t| {
                (0..views).map(|v| {
                    t.column(
                        &display,
                        display.sample_index(
                            display.holes_x / 2,
                            display.holes_y / 2,
                            (v % display.views_u as usize) as u32,
                            (v / display.views_u as usize) as u32,
                        ),
                    )
                    .len()
                })
            })
            .max()
            .unwrap_or(0),
    );
    let (_, geometric) = time_kernels(&display, sub_rays)?;
    Ok(WaveFigures {
        name: name.to_string(),
        display,
        build,
        stencil: (stencil.0, stencil.1),
        fft: (fft.0, fft.1),
        chosen,
        fft_first: fft.2,
        spectra_bytes: fft.3 - stencil.3,
        mads,
        bytes,
        csr_bytes,
        taps,
        geometric_forward: geometric.forward,
        geometric_adjoint: geometric.adjoint,
    })
}

/// The `wave` section: the wave-optics operator (per-view stencils, docs/design.md §2.7) on the paper,
/// lenslet, pinhole and dense presets, against the geometric CSR kernels of the same display and against the
/// multiply-add roofline, all measured in the same run.
pub fn wave_bench(sub_rays: u32) -> Result<String> {
    let peak = eyekey_core::physics::transport::multiply_add_peak_gflops(20_000_000);
    let mut out = format!(
        "Roofline: {peak:.1} GFLOP/s, the multiply-add peak of the stencils' own vector code ({}) on {} \
         threads (`multiply_add_peak_gflops`: register-resident chains, no loads or stores). The kernels take \
         a few hundred KiB and a light field a few MiB, so the products run from cache; the roofline is the FMA \
         units' throughput and FLOPs (2 per multiply-add) are the measure for the stencils. The FFT products \
         (`transport/fft.rs`) compute the same operator on a zero-padded grid; their work does not grow with \
         the taps. \"Chosen\" is what the operators pick by their cost model (`fft_is_cheaper`). \
         \"Geometric\" is the same display's traced CSR operator and fused kernels (one T for every band), \
         built and timed in the same run.\n\n",
        eyekey_core::physics::transport::vector_isa(),
        rayon::current_num_threads()
    );
    out.push_str(&table_header(&[
        "display",
        "kernel taps per sample (mean / largest)",
        "one person's 4-band kernels built",
        "stencils held",
        "as CSR it would take",
        "stencils: S = Σ c_n T_n L_n / adjoint",
        "stencils' fraction of roofline (forward / adjoint)",
        "FFT: S / adjoint",
        "FFT: first product (spectra) / spectra held",
        "chosen",
        "geometric CSR A·L / Aᵀ·y",
        "chosen / geometric time (forward / adjoint)",
    ]));
    for name in ["paper", "secure", "lenslet", "pinhole", "dense"] {
        let f = wave_figures(name, sub_rays)?;
        let d = &f.display;
        let flops = 2.0 * f.mads as f64;
        let chosen = match f.chosen {
            ProductMethod::Stencil => f.stencil,
            ProductMethod::Fft => f.fft,
        };
        let mib = |b: usize| b as f64 / (1 << 20) as f64;
        writeln!(
            out,
            "| {} ({}×{} holes, {}×{} views) | {:.0} / {} | {:.3} s | {:.2} MiB | {:.0} MiB | {:.2} / {:.2} ms | {:.0} % / {:.0} % | {:.2} / {:.2} ms | {:.1} ms / {:.1} MiB | {} | {:.2} / {:.2} ms | {:.1}× / {:.1}× |",
            f.name,
            d.holes_x,
            d.holes_y,
            d.views_u,
            d.views_v,
            f.taps.0,
            f.taps.1,
            f.build,
            mib(f.bytes),
            mib(f.csr_bytes),
            f.stencil.0 * 1e3,
            f.stencil.1 * 1e3,
            100.0 * flops / f.stencil.0 / 1e9 / peak,
            100.0 * flops / f.stencil.1 / 1e9 / peak,
            f.fft.0 * 1e3,
            f.fft.1 * 1e3,
            f.fft_first * 1e3,
            mib(f.spectra_bytes),
            match f.chosen {
                ProductMethod::Stencil => "stencils",
                ProductMethod::Fft => "FFT",
            },
            f.geometric_forward * 1e3,
            f.geometric_adjoint * 1e3,
            chosen.0 / f.geometric_forward,
            chosen.1 / f.geometric_adjoint,
        )?;
    }
    writeln!(
        out,
        "\npeak resident memory: {:.0} MB",
        peak_memory_bytes() as f64 / 1e6
    )?;
    Ok(out)
}

/// One person's 4-band wave operators on `display` at `eye`, built with `sub_rays` from `sequence` and `seed`,
/// applied to a fixed light field: the retinal image, and the seconds the build took.
fn kernel_image(
    display: &DisplayGeometry,
    (eye, dioptres): (EyePosition, f64),
    sub_rays: u32,
    seed: u64,
    sequence: SubRaySequence,
) -> Result<(Vec<f64>, f64)> {
    use eyekey_core::physics::observer::{transports, Lens};
    let w = accommodated_bench_wavefront(dioptres)?;
    let opts = TransportOptions {
        sub_rays,
        seed,
        sequence,
        ..Default::default()
    };
    let lens = Lens::Eye {
        wavefront: &w,
        reference_nm: 555.0,
    };
    let t0 = Instant::now();
    let ts = transports(display, lens, eye, &opts, Optics::Wave, &TransportCache::disabled())?;
    let secs = t0.elapsed().as_secs_f64();
    let n = display.n_bands();
    let coupling: Vec<[f32; 3]> = (0..n).map(|k| [0.3 + 0.1 * k as f32, 0.5, 0.2]).collect();
    let l: Vec<f32> = (0..ts[0].n_samples() * n)
        .map(|i| ((i * 7919) % 13) as f32 / 13.0)
        .collect();
    let mut y = vec![0f32; ts[0].n_pixels() * 3];
    for (band, t) in ts.iter().enumerate() {
        t.forward_band_lms(None, &l, n, band, coupling[band], band > 0, &mut y);
    }
    Ok((y.into_iter().map(f64::from).collect(), secs))
}

/// The `kernels` section: how far one person's kernels are from converged, for independent draws against the
/// Kronecker sequence, at the job's sub-rays and at the target guard's.
pub fn kernels_bench(sub_rays: u32) -> Result<String> {
    const SEEDS: u64 = 4;
    const REFERENCE: u32 = 32;
    let mut out = format!(
        "One person's 4-band wave operators (the bench eye: 6 mm pupil, defocus, coma, spherical; {} \
         wavelengths per band), each applied to the same light field. The error is the RMS difference of the \
         retinal image from a reference, relative to the reference's RMS variation about its mean (the picture's \
         content, which the attackers correlate), as the RMS over {SEEDS} seeds. The reference is the mean of two \
         Kronecker builds of {REFERENCE}× the job's sub-rays under other seeds (each rotation is an independent \
         unbiased estimate; independent draws converge too erratically on `pinhole` to serve); its own error is \
         about half the two halves' difference, shown. The job draws {sub_rays} sub-rays; the target guard's \
         second look {}×. On lenslet displays, kernels by quadrature (no sub-rays, docs/design.md §2.7): its \
         error and build time (tables cached) in the last column.\n\n",
        eyekey_core::physics::transport::DEFAULT_WAVELENGTHS_PER_BAND,
        pipeline::GUARD_SUB_RAYS,
    );
    let multiples = [1, 4, 8];
    let mut header = vec!["display, eye".to_string(), "reference's own error".to_string()];
    for m in multiples {
        header.push(format!("{}× sub-rays: independent / Kronecker", m));
    }
    header.push("build at 1× (s)".to_string());
    header.push("quadrature: error / build (s)".to_string());
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    out.push_str(&table_header(&header));
    let rel = |a: &[f64], r: &[f64]| {
        let e: f64 = a.iter().zip(r).map(|(x, y)| (x - y).powi(2)).sum();
        let mean = r.iter().sum::<f64>() / r.len() as f64;
        let n: f64 = r.iter().map(|y| (y - mean).powi(2)).sum();
        e / n
    };
    for name in ["paper", "secure", "lenslet", "pinhole"] {
        let display = DisplayGeometry::preset(name)?;
        for (x_mm, dioptres) in [(0.0, 0.0), (2.0, 0.0), (0.0, 2.0)] {
            let eye = (
                EyePosition {
                    x_mm,
                    ..Default::default()
                },
                dioptres,
            );
            let big = REFERENCE * sub_rays;
            let (a, _) = kernel_image(&display, eye, big, 1001, SubRaySequence::Kronecker)?;
            let (b, _) = kernel_image(&display, eye, big, 1002, SubRaySequence::Kronecker)?;
            let reference: Vec<f64> = a.iter().zip(&b).map(|(x, y)| 0.5 * (x + y)).collect();
            let own = 0.5 * rel(&a, &b).sqrt();
            let focus = if dioptres == 0.0 {
                String::new()
            } else {
                format!(", accommodated {dioptres:+} D")
            };
            let mut row = format!("| {name}, {x_mm} mm aside{focus} | {:.3} % |", 100.0 * own);
            let mut build = 0.0;
            for m in multiples {
                let mut cells = Vec::new();
                for sequence in [SubRaySequence::Independent, SubRaySequence::Kronecker] {
                    let mut sum = 0.0;
                    for seed in 1..=SEEDS {
                        let (img, secs) = kernel_image(&display, eye, m * sub_rays, seed, sequence)?;
                        if m == 1 {
                            build += secs / (2 * SEEDS) as f64;
                        }
                        sum += rel(&img, &reference);
                    }
                    cells.push(100.0 * (sum / SEEDS as f64).sqrt());
                }
                write!(row, " {:.3} % / {:.3} % |", cells[0], cells[1])?;
            }
            write!(row, " {build:.2} |")?;
            if display.aperture == eyekey_core::physics::display::Aperture::Lenslet {
                // Deterministic: one build is every build; the second is timed with the tables cached, as a job
                // finds them.
                let _ = kernel_image(&display, eye, sub_rays, 1, SubRaySequence::Quadrature)?;
                let (img, secs) = kernel_image(&display, eye, sub_rays, 1, SubRaySequence::Quadrature)?;
                writeln!(row, " {:.3} % / {secs:.2} |", 100.0 * rel(&img, &reference).sqrt())?;
            } else {
                writeln!(row, " sampled (pinholes) |")?;
            }
            print!("{row}");
            std::io::stdout().flush()?;
            out.push_str(&row);
        }
    }
    Ok(out)
}

/// One person's 4-band kernels (the bench eye at the seat) built by quadrature with its tables cached, against
/// the sampled kernels with their ray bundles cached (as an evaluation of many people finds both), alternately,
/// five rounds; the fastest and slowest round of each.
fn kernel_time_rows(sub_rays: u32) -> Result<String> {
    let mut out = String::from(
        "One person's 4-band kernels (the bench eye at the seat, 12 wavelengths, at its own focus and accommodated \
         by 2 D as an evaluation's focus sweep reaches), built by quadrature with its \
         tables cached against the sampled kernels (Kronecker, the job's sub-rays) with their ray bundles cached, \
         as an evaluation of many people finds both; alternately, five rounds, fastest–slowest:\n\n",
    );
    out.push_str(&table_header(&[
        "display",
        "quadrature",
        "sampled",
        "quadrature / sampled (fastest)",
    ]));
    for (name, dioptres) in [("secure", 0.0), ("secure", 2.0), ("lenslet", 0.0), ("lenslet", 2.0)] {
        let display = DisplayGeometry::preset(name)?;
        let eye = (EyePosition::default(), dioptres);
        let mut times = [Vec::new(), Vec::new()];
        for round in 0..6 {
            for (at, sequence) in [SubRaySequence::Quadrature, SubRaySequence::Kronecker]
                .into_iter()
                .enumerate()
            {
                let (_, secs) = kernel_image(&display, eye, sub_rays, 1, sequence)?;
                // The first round fills the caches.
                if round > 0 {
                    times[at].push(secs);
                }
            }
        }
        let span = |t: &[f64]| {
            let (lo, hi) = t
                .iter()
                .fold((f64::INFINITY, 0f64), |(lo, hi), v| (lo.min(*v), hi.max(*v)));
            (lo, hi)
        };
        let ((ql, qh), (sl, sh)) = (span(&times[0]), span(&times[1]));
        let row = format!(
            "| {name}, accommodated {dioptres:+} D | {:.1}–{:.1} ms | {:.1}–{:.1} ms | {:.2}× |\n",
            ql * 1e3,
            qh * 1e3,
            sl * 1e3,
            sh * 1e3,
            ql / sl
        );
        print!("{row}");
        out.push_str(&row);
    }
    Ok(out)
}

/// The target's view of its own frames (the `secure` and `lenslet` jobs' defaults, a PIN slip, a held-out
/// target) through the kernels a job builds, against converged kernels: the mean of two Kronecker builds of 32×
/// the job's sub-rays under other seeds, relative to that view's contrast, at the seat and 2 mm aside. Encoded
/// frames are where the kernels' error matters: they are tuned so that views cancel, and a view's contrast is a
/// small part of the light.
fn encoded_view_bench(sub_rays: u32) -> Result<String> {
    let mut out = String::from(
        "The target's view of its own frames (each display's job with its default options, a PIN slip, a held-out \
         target), through the kernels a job builds, against converged kernels (the mean of two Kronecker builds of \
         32× the job's sub-rays under other seeds; its own error is half their difference), relative to the view's \
         contrast; the sampled kernels as the RMS over 4 seeds:\n\n",
    );
    out.push_str(&table_header(&[
        "display, eye",
        "reference's own error",
        "quadrature",
        "Kronecker, the job's sub-rays (`sequence: kronecker`)",
    ]));
    for name in ["secure", "lenslet"] {
        let display = DisplayGeometry::preset(name)?;
        let (document, text) = super::experiment::pin_slip_of(display.holes_x * 4, display.holes_y * 4, "4821");
        let target = eyekey_core::physics::population::sample_population(1, 4242, Default::default()).remove(0);
        let spec = JobSpec {
            display: display.clone(),
            target: target.clone(),
            target_label: "bench".into(),
            observers: vec![],
            document,
            decoy: None,
            options: EncodeOptions {
                document_text: Some(text),
                seed: Some(crate::research::EXPERIMENT_SEED),
                ..Default::default()
            },
        };
        let cache = TransportCache::disabled();
        let encoded = pipeline::encode(&spec, &cache, &|_| {}, &AtomicBool::new(false))?;
        let l = &encoded.light_field;
        for x_mm in [0.0, 2.0] {
            let eye = EyePosition {
                x_mm,
                ..Default::default()
            };
            let view = |sequence: SubRaySequence, rays: u32, seed: u64| -> Result<Vec<f64>> {
                let opts = TransportOptions {
                    sub_rays: rays,
                    seed,
                    sequence,
                    ..Default::default()
                };
                let o = Observer::new(&display, &target, eye, &opts, Optics::Wave, &cache)?;
                let mut y = vec![0f32; o.n_pixels() * 3];
                o.forward_lms(l, &mut y);
                Ok(y.into_iter().map(f64::from).collect())
            };
            let a = view(SubRaySequence::Kronecker, 32 * sub_rays, 1001)?;
            let b = view(SubRaySequence::Kronecker, 32 * sub_rays, 1002)?;
            let reference: Vec<f64> = a.iter().zip(&b).map(|(x, y)| 0.5 * (x + y)).collect();
            let rel = |v: &[f64]| {
                let mean = reference.iter().sum::<f64>() / reference.len() as f64;
                let e: f64 = v.iter().zip(&reference).map(|(x, y)| (x - y).powi(2)).sum();
                let n: f64 = reference.iter().map(|y| (y - mean).powi(2)).sum();
                100.0 * (e / n).sqrt()
            };
            // a is half the two builds' difference from their mean.
            let own = rel(&a);
            let quadrature = rel(&view(SubRaySequence::Quadrature, sub_rays, 1)?);
            let sampled: f64 = (1..=4)
                .map(|seed| view(SubRaySequence::Kronecker, sub_rays, seed).map(|v| rel(&v).powi(2)))
                .sum::<Result<f64>>()?;
            let row = format!(
                "| {name}, {x_mm} mm aside | {own:.3} % | {quadrature:.3} % | {:.3} % |\n",
                (sampled / 4.0).sqrt()
            );
            print!("{row}");
            out.push_str(&row);
        }
    }
    Ok(out)
}

/// A multiplex problem on `display` with `k` observers (target + representative + population decoys).
pub struct BenchProblem {
    /// Observers (target first).
    pub observers: Vec<Observer>,
    /// Objective images.
    pub objectives: Vec<Vec<f32>>,
    /// ‖S'_t‖².
    pub energy: f64,
    /// Tikhonov μ (mean-square).
    pub tikhonov: f64,
}

impl BenchProblem {
    /// Builds the problem: the target reads a PIN slip, every other observer is shown a noise mask.
    pub fn new(display: &DisplayGeometry, k: usize, sub_rays: u32) -> Result<Self> {
        Self::with_optics(display, k, sub_rays, Optics::Geometric)
    }

    /// [`Self::new`] under `optics`.
    pub fn with_optics(display: &DisplayGeometry, k: usize, sub_rays: u32, optics: Optics) -> Result<Self> {
        let opts = TransportOptions {
            sub_rays,
            ..Default::default()
        };
        let target = VisionProfile::perfect();
        let mut people = vec![target];
        people.extend(eyekey_core::physics::population::sample_population(
            k.saturating_sub(1),
            7,
            Default::default(),
        ));
        let observers = people
            .iter()
            .map(|p| {
                Observer::new(
                    display,
                    p,
                    EyePosition::default(),
                    &opts,
                    optics,
                    &TransportCache::disabled(),
                )
            })
            .collect::<Result<Vec<_>, _>>()?;
        let g = observers[0].grid();
        let doc = eyekey_core::imaging::glyphs::render_text(
            &["PIN", "4821"],
            g.width * 4,
            g.height * 4,
            (g.width / 8).max(1),
        );
        let mut objectives = vec![observers[0].objective(&doc, eyekey_core::encoding::pipeline::OBJECTIVE_LEVEL)];
        for (i, o) in observers.iter().enumerate().skip(1) {
            objectives.push(o.objective(
                &noise_decoy(g.width, g.height, 2, i as u64),
                eyekey_core::encoding::pipeline::OBJECTIVE_LEVEL,
            ));
        }
        let energy = objectives[0].iter().map(|v| (*v as f64).powi(2)).sum();
        Ok(Self {
            observers,
            objectives,
            energy,
            tikhonov: 1e-4,
        })
    }

    /// The objective over the problem.
    pub fn objective(&self) -> MultiplexObjective<'_> {
        let terms = self
            .observers
            .iter()
            .zip(&self.objectives)
            .map(|(o, obj)| Term {
                observer: o,
                objective: obj.clone(),
                weight: 1.0,
                leak: None,
            })
            .collect();
        MultiplexObjective::new(terms, self.observers[0].coupling.len(), self.energy, self.tikhonov)
    }

    /// Writes the problem for an external solver: `A.mtx` (Matrix Market, the stacked, weighted and normalised
    /// system √(w_k/E)·(C_k ⊗ T_k) with the light field's band-interleaved column order), `b.txt`, and
    /// `problem.json` (sizes, bounds, μ).
    pub fn export(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir)?;
        let n = self.observers[0].coupling.len();
        let cols = self.observers[0].n_samples() * n;
        let scale = (1.0 / self.energy).sqrt();
        let mut entries: Vec<(usize, usize, f64)> = Vec::new();
        let mut b: Vec<f64> = Vec::new();
        let mut row0 = 0;
        for (o, obj) in self.observers.iter().zip(&self.objectives) {
            let m = o.transports[0]
                .sparse()
                .context("the exported problem is geometric (CSR)")?
                .0;
            for r in 0..m.n_rows {
                for e in m.indptr[r] as usize..m.indptr[r + 1] as usize {
                    let (c, v) = (m.indices[e] as usize, m.values[e] as f64);
                    for (band, cn) in o.coupling_f64.iter().enumerate() {
                        for (a, ca) in cn.iter().enumerate() {
                            if *ca != 0.0 {
                                entries.push((row0 + r * 3 + a, c * n + band, scale * v * ca));
                            }
                        }
                    }
                }
            }
            b.extend(obj.iter().map(|v| scale * *v as f64));
            row0 += m.n_rows * 3;
        }
        let mut f = std::io::BufWriter::new(std::fs::File::create(dir.join("A.mtx"))?);
        writeln!(f, "%%MatrixMarket matrix coordinate real general")?;
        writeln!(f, "{} {} {}", row0, cols, entries.len())?;
        for (r, c, v) in &entries {
            writeln!(f, "{} {} {:e}", r + 1, c + 1, v)?;
        }
        f.flush()?;
        let mut fb = std::io::BufWriter::new(std::fs::File::create(dir.join("b.txt"))?);
        for v in &b {
            writeln!(fb, "{v:e}")?;
        }
        fb.flush()?;
        let meta = serde_json::json!({
            "rows": row0, "cols": cols, "nnz": entries.len(), "lower": 0.0, "upper": 1.0,
            "tikhonov_mean_square": self.tikhonov,
            "objective": "||A x - b||^2 + mu * ||x||^2 / cols",
            "x0": "0.5 everywhere",
        });
        std::fs::write(dir.join("problem.json"), serde_json::to_string_pretty(&meta)?)?;
        Ok(())
    }
}

/// The solvers [`solver_bench`] times.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Method {
    Fista,
    Diagonal,
    Spg,
}

/// Solver figures for one problem; returns Markdown lines and (f*, seconds to reach f*(1+1e-3)).
pub fn solver_bench(problem: &BenchProblem, label: &str) -> Result<(String, f64, f64)> {
    let obj = problem.objective();
    let x0 = vec![0.5f32; obj.dim()];
    let cancel = AtomicBool::new(false);
    // Reference optimum: a long run with a tight tolerance.
    let opts = SolverOptions {
        max_iterations: 1500,
        tolerance: 1e-9,
        patience: 20,
        ..Default::default()
    };
    let reference = minimise(&obj, x0.clone(), 0.0, 1.0, &opts, &mut |_| {}, &cancel);
    let f_star = reference.objective;
    let goal = f_star * (1.0 + 1e-3);
    let mut out = String::new();
    let mut secs_default = f64::NAN;
    // Timed runs from the same start, FISTA with the uniform step 1/L (the default) and with the diagonal metric,
    // and the spectral projected gradient: record the wall time of every iteration and stop at f*(1 + 1e-3).
    for (method, step) in [
        (Method::Fista, "step 1/L (default)"),
        (Method::Diagonal, "diagonal metric"),
        (Method::Spg, "spectral projected gradient"),
    ] {
        let opts = SolverOptions {
            preconditioned: method == Method::Diagonal,
            ..opts.clone()
        };
        let start = Instant::now();
        let mut times = Vec::new();
        let stop = AtomicBool::new(false);
        let mut record = |p: eyekey_core::encoding::solver::Progress| {
            times.push((p.iteration, p.objective, start.elapsed().as_secs_f64()));
            if p.objective <= goal {
                stop.store(true, std::sync::atomic::Ordering::Relaxed);
            }
        };
        let run = match method {
            Method::Spg => minimise_spg(&obj, x0.clone(), 0.0, 1.0, &opts, &mut record, &stop),
            _ => minimise(&obj, x0.clone(), 0.0, 1.0, &opts, &mut record, &stop),
        };
        let hit = times.iter().find(|(_, f, _)| *f <= goal + 1e-12).copied();
        let (its, secs) = hit.map(|(i, _, t)| (i, t)).unwrap_or((run.iterations, run.seconds));
        let per_it = match (times.first(), times.last()) {
            (Some(a), Some(b)) if times.len() > 1 => (b.2 - a.2) / (times.len() - 1) as f64,
            _ => run.seconds,
        };
        let step = match method {
            // Each backtrack is one objective evaluation more than the iterations count.
            Method::Spg => format!("{step} ({} line-search backtracks)", run.restarts),
            _ => step.to_string(),
        };
        writeln!(
            out,
            "| {label}, {step} | {} | {} | {:.4e} | {} | {:.2} s | {:.1} ms | {:.0} MB |",
            problem.observers.len(),
            obj.dim(),
            f_star,
            its,
            secs,
            per_it * 1e3,
            peak_memory_bytes() as f64 / 1e6
        )?;
        if method == Method::Fista {
            secs_default = secs;
        }
    }
    Ok((out, f_star, secs_default))
}

/// One evaluation of a k-observer wave-optics objective (value and gradient, as the solver calls it) with the
/// terms' kernels on one grid per band (the views' transforms shared) and with each term's own products,
/// timed alternately in the same run; and the shared grids' set-up (every term's kernel spectra). Rows for
/// each k in `ks` on `display`.
pub fn shared_transforms_rows(display: &DisplayGeometry, sub_rays: u32, ks: &[usize], label: &str) -> Result<String> {
    let mut out = String::new();
    for &k in ks {
        let problem = BenchProblem::with_optics(display, k, sub_rays, Optics::Wave)?;
        let picked = problem.objective().shares_transforms();
        let start = Instant::now();
        let shared = problem.objective().with_shared_transforms();
        let setup = start.elapsed().as_secs_f64();
        let separate = problem.objective().without_shared_transforms();
        let x: Vec<f32> = (0..shared.dim())
            .map(|i| 0.2 + 0.6 * ((i * 37 % 101) as f32 / 101.0))
            .collect();
        let mut grad = vec![0f32; x.len()];
        let mut time = |o: &MultiplexObjective<'_>, reps: usize| {
            let start = Instant::now();
            for _ in 0..reps {
                std::hint::black_box(o.value_and_gradient(&x, &mut grad));
            }
            start.elapsed().as_secs_f64() / reps as f64
        };
        // Warm both (the own products' spectra are computed on first use), then alternate.
        time(&separate, 3);
        time(&shared, 3);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for _ in 0..3 {
            a.push(time(&separate, 10));
            b.push(time(&shared, 10));
        }
        let best = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
        let range = |v: &[f64]| {
            let (lo, hi) = (best(v), v.iter().copied().fold(0.0, f64::max));
            format!("{:.2}–{:.2}", lo * 1e3, hi * 1e3)
        };
        writeln!(
            out,
            "| {label}, {k} observers | {} | {} ms | {} ms | {:.2}× | {:.0} ms |",
            if picked { "shared" } else { "own" },
            range(&a),
            range(&b),
            best(&b) / best(&a),
            setup * 1e3
        )?;
    }
    Ok(out)
}

/// A solve's objective along the way: after 50, 100, 200 iterations (those it ran) and at its end.
fn objective_path(history: &[f64]) -> String {
    let mut parts: Vec<String> = [50, 100, 200]
        .iter()
        .filter(|&&k| k < history.len())
        .map(|&k| format!("{:.5} at {k}", history[k - 1]))
        .collect();
    if let Some(last) = history.last() {
        parts.push(format!("{last:.5} at {}", history.len()));
    }
    parts.join(", ")
}

/// Replaces the section between `<!-- bench:NAME -->` and `<!-- /bench:NAME -->` in a Markdown file (appending
/// the section if absent).
pub fn write_section(path: &Path, name: &str, body: &str) -> Result<()> {
    let start = format!("<!-- bench:{name} -->");
    let end = format!("<!-- /bench:{name} -->");
    let old = std::fs::read_to_string(path).unwrap_or_default();
    let block = format!("{start}\n{body}{end}");
    let new = match (old.find(&start), old.find(&end)) {
        (Some(a), Some(b)) if b > a => format!("{}{}{}", &old[..a], block, &old[b + end.len()..]),
        _ => format!(
            "{}{}{}\n",
            old,
            if old.is_empty() || old.ends_with('\n') {
                ""
            } else {
                "\n"
            },
            block
        ),
    };
    std::fs::write(path, new).with_context(|| format!("writing {}", path.display()))
}

/// An option of the `job` section other than the default.
struct JobOverride {
    /// Appended to the section's name (`job-near-pupil`, `job-decoy-weight`).
    section: &'static str,
    /// The command-line flag that asked for it, with a leading space.
    flag: String,
    /// What it changes, for the section's text.
    what: String,
}

/// The `job` section's options other than the default, as `args` gives them.
fn job_overrides(args: &BenchArgs) -> Vec<JobOverride> {
    let mut overrides = Vec::new();
    if let Some(n) = args.near_pupil_decoys {
        overrides.push(JobOverride {
            section: "-near-pupil",
            flag: format!(" --near-pupil-decoys {n}"),
            what: format!("{n} near-pupil decoys"),
        });
    }
    if let Some(w) = args.decoy_weight {
        overrides.push(JobOverride {
            section: "-decoy-weight",
            flag: format!(" --decoy-weight {w}"),
            what: format!("decoys at weight {w}"),
        });
    }
    overrides
}

/// The benchmark sections `eyekey bench --section` accepts besides `all`, in the order they run.
const SECTIONS: [&str; 6] = ["transport", "wave", "kernels", "solver", "encode", "job"];

/// What every section of one `eyekey bench` run shares.
struct BenchRun<'a> {
    args: &'a BenchArgs,
    display: DisplayGeometry,
    /// When the figures were measured (UTC, to the minute).
    stamp: String,
    /// The command line that reproduces the figures.
    cmd: String,
}

/// `eyekey bench`: runs the selected sections; each prints its Markdown and replaces its section of `args.out`.
pub fn run(args: &BenchArgs) -> Result<()> {
    if args.section == "scale" {
        let stamp = chrono::Utc::now().format("%Y-%m-%d %H:%M UTC").to_string();
        let body = super::scale::run(args.database_url.as_deref(), &stamp)?;
        print!("{body}");
        return write_section(&args.out, "scale", &body);
    }
    let display = DisplayGeometry::preset(&args.preset)?;
    let all = args.section == "all";
    if !all && !SECTIONS.contains(&args.section.as_str()) {
        bail!(
            "--section must be transport, wave, kernels, solver, encode, job, all or scale, got {:?}",
            args.section
        );
    }
    let run = BenchRun {
        args,
        display,
        stamp: chrono::Utc::now().format("%Y-%m-%d %H:%M UTC").to_string(),
        cmd: format!(
            "eyekey bench --preset {} --sub-rays {} --section {}",
            args.preset, args.sub_rays, args.section
        ),
    };
    for name in SECTIONS {
        if all || args.section == name {
            let body = match name {
                "transport" => run.transport()?,
                "wave" => run.wave()?,
                "kernels" => run.kernels()?,
                "solver" => run.solver()?,
                "encode" => run.encode()?,
                _ => run.job()?,
            };
            print!("{body}");
            // A job with an option other than the default goes to a section of its own.
            let mut name = name.to_string();
            if name == "job" {
                name.extend(job_overrides(args).iter().map(|o| o.section));
            }
            write_section(&args.out, &name, &body)?;
        }
    }
    Ok(())
}

/// What the figures were measured with: the numerical crate is built at opt-level 2 in debug builds too.
fn build_kind() -> &'static str {
    if cfg!(debug_assertions) {
        "debug build: eyekey-core at opt-level 2"
    } else {
        "release build"
    }
}

impl BenchRun<'_> {
    /// The `transport` section: operator build and kernel figures.
    fn transport(&self) -> Result<String> {
        Ok(format!(
            "Measured {} by `{}` ({}):\n\n{}",
            self.stamp,
            self.cmd,
            build_kind(),
            transport_bench(&self.display, self.args.sub_rays)?
        ))
    }

    /// The `wave` section: the wave-optics stencils on four presets (the preset flag does not apply).
    fn wave(&self) -> Result<String> {
        Ok(format!(
            "Measured {} by `eyekey bench --sub-rays {} --section wave` ({}):\n\n{}",
            self.stamp,
            self.args.sub_rays,
            build_kind(),
            wave_bench(self.args.sub_rays)?
        ))
    }

    /// The `kernels` section: the kernels' sampling noise on four presets (the preset flag does not apply).
    fn kernels(&self) -> Result<String> {
        Ok(format!(
            "Measured {} by `eyekey bench --sub-rays {} --section kernels` ({}):\n\n{}\n{}\n{}",
            self.stamp,
            self.args.sub_rays,
            build_kind(),
            kernels_bench(self.args.sub_rays)?,
            encoded_view_bench(self.args.sub_rays)?,
            kernel_time_rows(self.args.sub_rays)?
        ))
    }

    /// The `solver` section: one row per problem size (2 and 8 observers); the 2-observer problem is also
    /// exported, with eyekey's result, when `--export` is given.
    fn solver(&self) -> Result<String> {
        let mut body = format!(
            "Measured {} by `{}` ({}). Time and iterations to reach an objective within 1e-3 \
             (relative) of the optimum found by a 1500-iteration, 1e-9-tolerance run from the same start.\n\n",
            self.stamp,
            self.cmd,
            build_kind()
        );
        body.push_str(&table_header(&[
            "problem",
            "observers",
            "unknowns",
            "optimum f*",
            "iterations to 1e-3",
            "time to 1e-3",
            "ms / iteration",
            "peak memory",
        ]));
        let label = format!("{} multiplex", self.args.preset);
        for k in [2usize, 8] {
            let problem = BenchProblem::new(&self.display, k, self.args.sub_rays)?;
            let export = if k == 2 { self.args.export.as_deref() } else { None };
            if let Some(dir) = export {
                problem.export(dir)?;
            }
            let (row, f_star, secs) = solver_bench(&problem, &label)?;
            body.push_str(&row);
            if let Some(dir) = export {
                std::fs::write(
                    dir.join("eyekey_result.json"),
                    serde_json::to_string_pretty(&serde_json::json!({"f_star": f_star, "seconds_to_1e-3": secs}))?,
                )?;
            }
        }
        // A problem of the kind the `paper` encode solves: wave optics, two observers.
        let wave = BenchProblem::with_optics(&self.display, 2, self.args.sub_rays, Optics::Wave)?;
        body.push_str(&solver_bench(&wave, &format!("{} wave multiplex", self.args.preset))?.0);
        body.push_str(
            "\nUnder wave optics (every band its own per-view kernels): one objective evaluation, value and gradient, \
             with every term's kernels on one grid per band so that the light field's views and the gradient's are \
             transformed once for all terms (\"shared\", docs/design.md §2.7), against each term's own products (its \
             stencils or its own FFTs, the light field gathered once), alternately in this run, three rounds of ten; \
             \"picked\" is what the objective chooses by its cost model. Set-up: building the objective with its \
             kernels' spectra on the shared grids.\n\n",
        );
        body.push_str(&table_header(&[
            "problem",
            "picked",
            "own products",
            "shared transforms",
            "shared / own (best)",
            "set-up",
        ]));
        body.push_str(&shared_transforms_rows(
            &self.display,
            self.args.sub_rays,
            &[2, 8, 13],
            &format!("{} wave", self.args.preset),
        )?);
        body.push_str(&fista_pass_rows(1_000_000));
        Ok(body)
    }

    /// The 2-observer job the `encode` section times: a PIN slip for a perfect eye, one sampled observer.
    fn encode_spec(&self) -> JobSpec {
        let display = &self.display;
        let g = (display.holes_x * 4, display.holes_y * 4);
        JobSpec {
            display: display.clone(),
            target: VisionProfile::perfect(),
            target_label: "bench".into(),
            observers: eyekey_core::physics::population::sample_population(1, 3, Default::default()),
            document: eyekey_core::imaging::glyphs::render_text(&["PIN", "4821"], g.0, g.1, (g.0 / 32).max(1)),
            decoy: None,
            options: EncodeOptions {
                population_decoys: 0,
                near_pupil_decoys: 0,
                sub_rays: self.args.sub_rays,
                // The paper's two-observer multiplexing (Eq. 14), as the target was set for.
                decoy_weight: Some(1.0),
                leak_weight: 0.0,
                ensure_target_reads: false,
                seed: Some(crate::research::EXPERIMENT_SEED),
                ..Default::default()
            },
        }
    }

    /// The `job` section: the `secure` preset's job with every default option (a sampled target, a PIN slip
    /// with its text hint), end to end from a cold start as a worker runs it (`run_job`: operators, solve, the
    /// default evaluation, bundle), with where the time goes; then a 1,000-person evaluation of its frames, cold
    /// and with the people's operators cached.
    fn job(&self) -> Result<String> {
        let display = DisplayGeometry::secure();
        let (document, text) = super::experiment::pin_slip_of(display.holes_x * 4, display.holes_y * 4, "4821");
        let spec = JobSpec {
            display: display.clone(),
            target: eyekey_core::physics::population::sample_population(1, 4242, Default::default()).remove(0),
            target_label: "bench".into(),
            observers: vec![],
            document,
            decoy: None,
            options: EncodeOptions {
                document_text: Some(text.clone()),
                near_pupil_decoys: self
                    .args
                    .near_pupil_decoys
                    .unwrap_or(EncodeOptions::default().near_pupil_decoys),
                decoy_weight: self.args.decoy_weight,
                seed: Some(crate::research::EXPERIMENT_SEED),
                ..Default::default()
            },
        };
        let cache = TransportCache::default();
        let dir = tempfile::tempdir()?;
        let cancel = AtomicBool::new(false);
        // What `run_job` does, in its two steps, into `dir/name`: the light field, and the seconds until the
        // operators were built (the encode's progress reaches 0.15 then), until the solve ended and in all, and
        // whether the target reads.
        let run_job = |spec: &JobSpec, name: &str| -> Result<(pipeline::Encoded, f64, f64, f64, bool)> {
            let marks = std::sync::Mutex::new(Vec::<(f64, f64)>::new());
            let t = Instant::now();
            let encoded = pipeline::encode(
                spec,
                &cache,
                &|p| {
                    marks
                        .lock()
                        .unwrap_or_else(|e| e.into_inner())
                        .push((p, t.elapsed().as_secs_f64()))
                },
                &cancel,
            )?;
            let t_solved = t.elapsed().as_secs_f64();
            let out = pipeline::write_outputs(spec, &encoded, &dir.path().join(name), true, &cache, &|_| {}, &cancel)?;
            let total = t.elapsed().as_secs_f64();
            let marks = marks.into_inner().unwrap_or_else(|e| e.into_inner());
            let t_cast = marks
                .iter()
                .find(|m| m.0 >= 0.15 - 1e-9)
                .map(|m| m.1)
                .unwrap_or(t_solved);
            let target_reads = out.evaluation.as_ref().map(|r| r.target.readable).unwrap_or(false);
            Ok((encoded, t_cast, t_solved, total, target_reads))
        };
        let (encoded, t_cast, t_solved, total, target_reads) = run_job(&spec, "job")?;
        let evaluate_1000 = |label: &str| -> Result<String> {
            let t = Instant::now();
            let ev = eyekey_core::evaluation::evaluate(
                &display,
                &encoded.light_field,
                &spec.document,
                pipeline::OBJECTIVE_LEVEL,
                &spec.target,
                &[],
                &eyekey_core::evaluation::EvaluationOptions::population_only(1000, Some(text.clone())),
                &cache,
                &|_| {},
                &cancel,
            )?;
            let p = ev.report.population.expect("a population was asked for");
            Ok(format!(
                "| 1,000-person evaluation, {label} | {:.1} s ({} of 1000 read) |
",
                t.elapsed().as_secs_f64(),
                p.readable_count
            ))
        };
        let overrides = job_overrides(self.args);
        let flags: String = overrides.iter().map(|o| o.flag.as_str()).collect();
        let but = if overrides.is_empty() {
            String::new()
        } else {
            let what: Vec<&str> = overrides.iter().map(|o| o.what.as_str()).collect();
            format!(" but {}", what.join(" and "))
        };
        let near_pupil = spec.options.near_pupil_decoys;
        let scale = encoded.solver.decoy_weight_scale;
        // A second job on the same server, its transport cache and ray bundles kept from the first: another
        // held-out person and PIN (the decoys and the evaluation's people are the same draws, the target's and
        // its near-pupil decoys' operators new).
        let (document2, text2) = super::experiment::pin_slip_of(display.holes_x * 4, display.holes_y * 4, "5930");
        let spec2 = JobSpec {
            target: eyekey_core::physics::population::sample_population(2, 4242, Default::default()).remove(1),
            document: document2,
            options: EncodeOptions {
                document_text: Some(text2),
                ..spec.options.clone()
            },
            ..spec.clone()
        };
        let (encoded2, _, t2_solved, total2, reads2) = run_job(&spec2, "job2")?;
        let second = format!(
            "| a second job on the same server (caches kept): another held-out person and PIN | {total2:.1} s \
             (operators and solve {t2_solved:.1} s, {} iterations: {}; evaluation and bundle {:.1} s; target \
             reads: {reads2}, decoy weights scaled by {:.3}) |\n",
            encoded2.solver.iterations,
            solves_text(&encoded2.solver.solves),
            total2 - t2_solved,
            encoded2.solver.decoy_weight_scale,
        );
        let cold = evaluate_1000("people's operators built")?;
        let warm = evaluate_1000("people's operators cached")?;
        Ok(format!(
            "Measured {} by `eyekey bench --section job{flags}` ({}, transport cache empty at the start): the \
             `secure` preset, every default option{but} ({} population and {near_pupil} near-pupil decoys at \
             weight {}, leak weight {}, {} iterations at most, {} sub-rays; evaluation: {} people, camera, key \
             sensitivity, head movement).\n\n{}\
             | the whole job (`run_job`: encode, evaluation, bundle) | {total:.1} s (target reads: {target_reads}, \
             decoy weights scaled by {scale:.3}) |\n\
             | of which: target's and decoys' operators | {t_cast:.1} s |\n\
             | of which: solve | {:.1} s ({} iterations, {}: {}; objective {}) |\n\
             | of which: evaluation and bundle | {:.1} s |\n{second}{cold}{warm}| peak resident memory | {:.0} MB |\n",
            self.stamp,
            build_kind(),
            spec.options.population_decoys,
            spec.options.decoy_weight_on(&spec.display),
            spec.options.leak_weight,
            spec.options.max_iterations,
            spec.options.sub_rays,
            spec.options.evaluation_population,
            table_header(&["quantity", "value"]),
            t_solved - t_cast,
            encoded.solver.iterations,
            encoded.solver.termination,
            solves_text(&encoded.solver.solves),
            objective_path(&encoded.solver.objective_history),
            total - t_solved,
            peak_memory_bytes() as f64 / 1e6
        ))
    }

    /// The `encode` section: a whole cold-start encode (transport, solve, bundle written to a temporary
    /// directory).
    fn encode(&self) -> Result<String> {
        let cache = TransportCache::disabled();
        let spec = self.encode_spec();
        let dir = tempfile::tempdir()?;
        let cancel = AtomicBool::new(false);
        let mut trace = CpuTrace::start();
        let t = trace.start;
        let encoded = pipeline::encode(&spec, &cache, &|_| {}, &cancel)?;
        let t_solve = t.elapsed().as_secs_f64();
        trace.finish();
        let solve_began = t_solve - encoded.solver.seconds;
        let (busy_before, busy_solving) = (trace.busy(0.0, solve_began), trace.busy(solve_began, t_solve));
        pipeline::write_outputs(
            &spec,
            &encoded,
            &dir.path().join("bundle"),
            false,
            &cache,
            &|_| {},
            &cancel,
        )?;
        let total = t.elapsed().as_secs_f64();
        // The target guard's second look alone, built again as the encoder builds it (another seed, more sub-rays).
        let o = &spec.options;
        let t_check = Instant::now();
        Observer::new(
            &spec.display,
            &spec.target,
            EyePosition::default(),
            &pipeline::guard_transport(o),
            o.optics,
            &cache,
        )?;
        let t_check = t_check.elapsed().as_secs_f64();
        Ok(format!(
            "Measured {} by `{}` ({}, transport cache disabled: a cold start).\n\n{}\
             | whole 2-observer encode (transport, solve, bundle) | {total:.2} s |\n\
             | of which operators (2 observers × 4 bands; the target guard's second look, one person at {}× the sub-rays) and set-up | {:.2} s ({busy_before:.2} cores busy of {}) |\n\
             | of which the guard's second look (built again apart) | {t_check:.2} s |\n\
             | of which solve | {:.2} s ({} iterations, {}; {busy_solving:.2} cores busy) |\n\
             | bundle write | {:.2} s |\n| peak resident memory | {:.0} MB |\n",
            self.stamp,
            self.cmd,
            build_kind(),
            table_header(&["quantity", "value"]),
            pipeline::GUARD_SUB_RAYS,
            t_solve - encoded.solver.seconds,
            rayon::current_num_threads(),
            encoded.solver.seconds,
            encoded.solver.iterations,
            encoded.solver.termination,
            total - t_solve,
            peak_memory_bytes() as f64 / 1e6
        ))
    }
}

/// FISTA's vector work per iteration at `n` unknowns: the projected step, the restart test's inner product and the
/// extrapolation as three rayon passes (the solver's loop before `solver::fista_pass`, here as the baseline)
/// against `fista_pass`'s one pass, alternately, three rounds of 30 iterations each; the median of each.
fn fista_pass_rows(n: usize) -> String {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let fill = |rng: &mut rand_chacha::ChaCha8Rng| (0..n).map(|_| rng.gen::<f32>()).collect::<Vec<f32>>();
    let (mut y, g, x) = (fill(&mut rng), fill(&mut rng), fill(&mut rng));
    let mut x_new = vec![0f32; n];
    let (step, beta) = (0.1f32, 0.5f32);
    let project = |v: f32| v.clamp(0.0, 1.0);
    let (mut three, mut one) = (Vec::new(), Vec::new());
    for _ in 0..3 {
        for _ in 0..30 {
            let t = Instant::now();
            x_new
                .par_iter_mut()
                .zip(y.par_iter().zip(g.par_iter()))
                .for_each(|(xn, (yi, gi))| *xn = project(yi - step * gi));
            let uphill: f64 = g
                .par_iter()
                .zip(x_new.par_iter().zip(x.par_iter()))
                .map(|(g, (a, b))| *g as f64 * (*a as f64 - *b as f64))
                .sum();
            y.par_iter_mut()
                .zip(x_new.par_iter().zip(x.par_iter()))
                .for_each(|(yi, (a, b))| *yi = project(a + beta * (a - b)));
            std::hint::black_box(uphill);
            three.push(t.elapsed().as_secs_f64() * 1e3);
        }
        for _ in 0..30 {
            let t = Instant::now();
            let uphill =
                eyekey_core::encoding::solver::fista_pass(&mut y, &g, &x, &mut x_new, step, None, beta, (0.0, 1.0));
            std::hint::black_box(uphill);
            one.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (three, one) = (median(&mut three), median(&mut one));
    format!(
        "\nThe solver's vector work per iteration at {n} unknowns (x⁺ = Π(y − ∇f/L), the restart test ⟨∇f, x⁺ − x⟩, \
         y = Π(x⁺ + β(x⁺ − x))), alternately in this run, three rounds of 30, medians: as three passes (36 MB moved) \
         {three:.2} ms, as `fista_pass`'s one (20 MB) {one:.2} ms: **{:.2}×**.\n",
        one / three
    )
}

/// An encode's solves in words: "1.000 × 261 converged, not read; 0.500 × 60 stopped, read; …" (the decoys'
/// weight scale, iterations, why each stopped and whether the target read its end).
fn solves_text(solves: &[eyekey_core::encoding::job::SolveStep]) -> String {
    let steps: Vec<String> = solves
        .iter()
        .map(|s| {
            let read = match s.target_reads {
                Some(true) => ", read",
                Some(false) => ", not read",
                None => "",
            };
            format!("{:.3} × {} {}{read}", s.decoy_weight_scale, s.iterations, s.termination)
        })
        .collect();
    steps.join("; ")
}
