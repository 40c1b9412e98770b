//! Box-constrained minimisation (paper Eq. 15: 0 ≤ L ≤ L_max) for 10⁶ unknowns and more.
//!
//! FISTA (Beck & Teboulle 2009) with gradient-based adaptive restart (O'Donoghue & Candès 2015) and a step
//! 1/L from a Lanczos estimate of the gradient's Lipschitz constant; optionally
//! ([`SolverOptions::preconditioned`]) in a diagonal metric: unknown i steps s_i/L_S, s_i the inverse of its
//! curvature row sum (a separable surrogate, De Pierro 1995) and L_S the Lipschitz constant of S^½ H S^½, so that
//! unknowns few observers see (small curvature) are not held to the step of the most-seen ones. Hand-written:
//! the generic crates either lack box constraints at this scale or allocate per iteration. For the non-convex
//! difference-maximisation objective the same L bounds the curvature from above (its extra terms are
//! concave), so each projected-gradient step still decreases the objective; a step whose objective rises
//! is undone and the momentum reset, which keeps the method monotone.
//!
//! ```
//! use eyekey_core::encoding::solver::{minimise, Objective, SolverOptions};
//! use std::sync::atomic::AtomicBool;
//! // f(x) = Σ (x_i − 2)², minimised over 0 ≤ x ≤ 1: the answer is x = 1.
//! struct Quad;
//! impl Objective for Quad {
//!     fn dim(&self) -> usize { 3 }
//!     fn value_and_gradient(&self, x: &[f32], g: &mut [f32]) -> f64 {
//!         let mut f = 0.0;
//!         for (xi, gi) in x.iter().zip(g.iter_mut()) { f += ((xi - 2.0) as f64).powi(2); *gi = 2.0 * (xi - 2.0); }
//!         f
//!     }
//! }
//! let r = minimise(&Quad, vec![0.0; 3], 0.0, 1.0, &SolverOptions::default(), &mut |_| {}, &AtomicBool::new(false));
//! assert!(r.x.iter().all(|v| (v - 1.0).abs() < 1e-6));
//! ```

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use rayon::prelude::*;

/// A differentiable objective over f32 vectors.
pub trait Objective: Sync {
    /// Number of unknowns.
    fn dim(&self) -> usize;
    /// f(x), writing ∇f(x) into `grad`.
    fn value_and_gradient(&self, x: &[f32], grad: &mut [f32]) -> f64;
    /// f(x) alone (defaults to the gradient path).
    fn value(&self, x: &[f32]) -> f64 {
        let mut g = vec![0f32; self.dim()];
        self.value_and_gradient(x, &mut g)
    }
    /// The Hessian-vector product of the convex (least-squares) part, used to estimate the Lipschitz constant.
    /// Defaults to a finite difference of gradients.
    fn curvature_product(&self, v: &[f32], out: &mut [f32]) {
        let zero = vec![0f32; self.dim()];
        let mut g0 = vec![0f32; self.dim()];
        self.value_and_gradient(&zero, &mut g0);
        self.value_and_gradient(v, out);
        out.par_iter_mut().zip(g0.par_iter()).for_each(|(o, g)| *o -= g);
    }
}

/// Why the solver stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
#[non_exhaustive]
pub enum Termination {
    /// The relative objective change stayed below the tolerance.
    Converged,
    /// The iteration cap was reached.
    MaxIterations,
    /// The cancel flag was raised.
    Cancelled,
    /// The objective became non-finite.
    NumericalFailure,
    /// A checkpoint stopped the solve ([`Checkpoint`]).
    Stopped,
}

impl Termination {
    /// The name used in JSON: `converged`, `max_iterations`, `cancelled`, `numerical_failure`, `stopped`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Converged => "converged",
            Self::MaxIterations => "max_iterations",
            Self::Cancelled => "cancelled",
            Self::NumericalFailure => "numerical_failure",
            Self::Stopped => "stopped",
        }
    }
}

impl std::fmt::Display for Termination {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct SolverOptions {
    /// Iteration cap.
    pub max_iterations: u32,
    /// Stop when |f_k − f_{k−1}| ≤ tolerance·|f_k| for `patience` consecutive iterations.
    pub tolerance: f64,
    /// Consecutive iterations under the tolerance needed to stop.
    pub patience: u32,
    /// No convergence is declared before this many iterations. Started from the end of a solve of a slightly
    /// different objective, the first iterations are plain gradient steps (the momentum restarts) that move f by
    /// little against its size, and the tolerance test can stop the solve before it has moved towards the new
    /// optimum at all.
    pub min_iterations: u32,
    /// Lanczos steps for the Lipschitz estimate ([`estimate_lipschitz`]).
    pub lanczos_steps: u32,
    /// A known Lipschitz constant (skips the Lanczos estimate).
    pub lipschitz: Option<f64>,
    /// Scale each unknown's step by the inverse of its curvature row sum (a diagonal, Jacobi-like metric; see
    /// [`jacobi_scales`]); without it every unknown takes the step 1/L.
    pub preconditioned: bool,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            max_iterations: 500,
            tolerance: 1e-6,
            patience: 5,
            min_iterations: 0,
            lanczos_steps: 12,
            lipschitz: None,
            preconditioned: false,
        }
    }
}

/// Progress of a running solve, passed to the callback once per iteration.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    /// Iterations done.
    pub iteration: u32,
    /// The iteration cap.
    pub max_iterations: u32,
    /// Objective at the latest iterate.
    pub objective: f64,
}

#[derive(Clone, Debug)]
pub struct SolveResult {
    /// The minimiser found (inside the box).
    pub x: Vec<f32>,
    /// f at `x`.
    pub objective: f64,
    /// Objective after each iteration.
    pub history: Vec<f64>,
    /// Iterations run.
    pub iterations: u32,
    /// Momentum restarts.
    pub restarts: u32,
    /// The Lipschitz constant used: of the curvature (step 1/L), or of S^½ H S^½ in the diagonal metric (steps
    /// s_i/L).
    pub lipschitz: f64,
    /// Why it stopped.
    pub termination: Termination,
    /// Wall time, seconds.
    pub seconds: f64,
}

fn norm(v: &[f32]) -> f64 {
    v.par_iter().map(|x| (*x as f64) * (*x as f64)).sum::<f64>().sqrt()
}

/// Estimates the largest eigenvalue of the objective's curvature (the gradient's Lipschitz constant) by `steps`
/// Lanczos steps ([`lanczos_top_eigenvalue`]), with a 10 % margin. On the `secure` job 8 steps give what 30 power
/// iterations gave to 6 digits, at a quarter of the curvature products (BENCHMARKS.md, "Whole job").
pub fn estimate_lipschitz(obj: &dyn Objective, steps: u32, seed: u64) -> f64 {
    lanczos_top_eigenvalue(obj, steps, seed).abs().max(1e-12) * 1.1
}

/// The largest eigenvalue of the objective's curvature H by `steps` Lanczos steps (Golub & Van Loan, *Matrix
/// Computations*, 4th ed., §10.1), from the same start as [`estimate_lipschitz`]: the largest eigenvalue of the
/// tridiagonal T_k = Q_kᵀ H Q_k, which is at least the Rayleigh quotient of k power iterations (both lie in the
/// same Krylov space, and T_k's top eigenvalue is the largest Rayleigh quotient there) and never above λ_max.
/// Without reorthogonalisation: lost orthogonality only repeats converged eigenvalues. No margin is added.
pub fn lanczos_top_eigenvalue(obj: &dyn Objective, steps: u32, seed: u64) -> f64 {
    let n = obj.dim();
    let mut v = start_vector(n, seed);
    let nv = norm(&v);
    if nv == 0.0 {
        return 0.0;
    }
    v.par_iter_mut().for_each(|x| *x /= nv as f32);
    let mut v_prev = vec![0f32; n];
    let mut w = vec![0f32; n];
    let (mut alpha, mut beta) = (Vec::new(), Vec::<f64>::new());
    for _ in 0..steps.max(1) {
        obj.curvature_product(&v, &mut w);
        let a = v
            .par_iter()
            .zip(w.par_iter())
            .map(|(x, y)| *x as f64 * *y as f64)
            .sum::<f64>();
        let (af, bf) = (a as f32, beta.last().copied().unwrap_or(0.0) as f32);
        w.par_iter_mut()
            .zip(v.par_iter().zip(v_prev.par_iter()))
            .for_each(|(wi, (vi, pi))| *wi -= af * vi + bf * pi);
        alpha.push(a);
        let b = norm(&w);
        if b <= 1e-12 * a.abs().max(1e-30) {
            break;
        }
        beta.push(b);
        std::mem::swap(&mut v_prev, &mut v);
        v.par_iter_mut()
            .zip(w.par_iter())
            .for_each(|(vi, wi)| *vi = wi / b as f32);
    }
    beta.truncate(alpha.len() - 1);
    tridiagonal_top_eigenvalue(&alpha, &beta)
}

/// The Lanczos start: xorshift, a cheap deterministic vector with positive entries in [0.5, 1.5).
fn start_vector(n: usize, seed: u64) -> Vec<f32> {
    let mut state = seed | 1;
    (0..n)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            0.5 + (state % 1000) as f32 / 1000.0
        })
        .collect()
}

/// The largest eigenvalue of the symmetric tridiagonal matrix with diagonal `a` and off-diagonal `b`, by
/// bisection on the Sturm sequence count (Golub & Van Loan §8.4.1) between Gershgorin bounds.
pub fn tridiagonal_top_eigenvalue(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len();
    assert!(n >= 1 && b.len() + 1 == n, "a tridiagonal matrix");
    let radius = |i: usize| (if i > 0 { b[i - 1].abs() } else { 0.0 }) + b.get(i).map_or(0.0, |v| v.abs());
    let mut lo = (0..n).map(|i| a[i] - radius(i)).fold(f64::INFINITY, f64::min);
    let mut hi = (0..n).map(|i| a[i] + radius(i)).fold(f64::NEG_INFINITY, f64::max);
    // How many eigenvalues lie below x: the negative pivots of T − xI = LDLᵀ.
    let below = |x: f64| {
        let (mut d, mut count) = (1.0f64, 0usize);
        for i in 0..n {
            let off = if i > 0 { b[i - 1] * b[i - 1] / d } else { 0.0 };
            d = a[i] - x - off;
            if d == 0.0 {
                d = -1e-300;
            }
            if d < 0.0 {
                count += 1;
            }
        }
        count
    };
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if below(mid) < n {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// The objective seen in the metric of a diagonal preconditioner: x = S^½ z, so its curvature is
/// S^½ H S^½ (what the Lanczos estimate measures when the steps are scaled by S).
struct Scaled<'a> {
    inner: &'a dyn Objective,
    half: Vec<f32>,
}

impl Objective for Scaled<'_> {
    fn dim(&self) -> usize {
        self.inner.dim()
    }
    fn value_and_gradient(&self, _: &[f32], _: &mut [f32]) -> f64 {
        unreachable!("only the curvature of a scaled objective is asked for")
    }
    fn curvature_product(&self, v: &[f32], out: &mut [f32]) {
        let sv: Vec<f32> = v.par_iter().zip(self.half.par_iter()).map(|(v, h)| v * h).collect();
        self.inner.curvature_product(&sv, out);
        out.par_iter_mut().zip(self.half.par_iter()).for_each(|(o, h)| *o *= h);
    }
}

/// The separable (Jacobi-like) step scales of a diagonal preconditioner: s_i = 1/Σ_j |H_ij| when H has
/// non-negative entries, estimated as 1/(H·1)_i (De Pierro 1995's separable surrogate; Fessler's SPS), with
/// each row sum floored at 10⁻³ of the largest so that unknowns nobody sees do not take unbounded steps.
/// The step of unknown i is s_i / L_S, L_S the Lipschitz constant of S^½ H S^½ measured by Lanczos steps, so
/// a wrong row sum costs speed, never convergence.
pub fn jacobi_scales(obj: &dyn Objective) -> Vec<f32> {
    let n = obj.dim();
    let ones = vec![1f32; n];
    let mut d = vec![0f32; n];
    obj.curvature_product(&ones, &mut d);
    let top = d.par_iter().map(|v| v.abs()).reduce(|| 0.0, f32::max);
    let floor = (top * 1e-3).max(f32::MIN_POSITIVE);
    d.par_iter().map(|v| 1.0 / v.max(floor)).collect()
}

/// Minimises `obj` over lower ≤ x ≤ upper from the warm start `x0`.
///
/// `progress` is called after every iteration; `cancel` is checked before every iteration.
pub fn minimise(
    obj: &dyn Objective,
    x0: Vec<f32>,
    lower: f32,
    upper: f32,
    options: &SolverOptions,
    progress: &mut dyn FnMut(Progress),
    cancel: &AtomicBool,
) -> SolveResult {
    minimise_judged(obj, x0, lower, upper, options, progress, cancel, None)
}

/// After every `every` iterations (and not after the last), `stop` is shown the iteration count and the iterate
/// x_k; when it answers true the solve ends there ([`Termination::Stopped`]) and returns x_k. Until then the
/// iterates are those of the solve without it, bit for bit.
pub struct Checkpoint<'a> {
    pub every: u32,
    pub stop: &'a mut dyn FnMut(u32, &[f32]) -> bool,
}

/// [`minimise`], with a [`Checkpoint`] that may end it early.
#[allow(clippy::too_many_arguments)]
pub fn minimise_judged(
    obj: &dyn Objective,
    x0: Vec<f32>,
    lower: f32,
    upper: f32,
    options: &SolverOptions,
    progress: &mut dyn FnMut(Progress),
    cancel: &AtomicBool,
    mut checkpoint: Option<Checkpoint<'_>>,
) -> SolveResult {
    assert!(
        checkpoint.as_ref().is_none_or(|c| c.every > 0),
        "checkpoints every 1 or more iterations"
    );
    let start = Instant::now();
    let n = obj.dim();
    assert_eq!(x0.len(), n, "warm start length");
    // The step: 1/L for every unknown, or s_i/L_S per unknown in a diagonal metric (the box projection is still a
    // clamp, the metric being diagonal).
    let (lipschitz, steps) = if options.preconditioned {
        let scales = jacobi_scales(obj);
        let half = scales.par_iter().map(|s| s.sqrt()).collect();
        let l = options
            .lipschitz
            .unwrap_or_else(|| estimate_lipschitz(&Scaled { inner: obj, half }, options.lanczos_steps, 12345));
        let inv = (1.0 / l) as f32;
        (l, Some(scales.into_par_iter().map(|s| s * inv).collect::<Vec<f32>>()))
    } else {
        let l = options
            .lipschitz
            .unwrap_or_else(|| estimate_lipschitz(obj, options.lanczos_steps, 12345));
        (l, None)
    };
    let step = (1.0 / lipschitz) as f32;
    let project = box_projection(lower, upper);
    let mut x: Vec<f32> = x0.into_par_iter().map(project).collect();
    let mut y = x.clone();
    let mut x_new = vec![0f32; n];
    let mut grad = vec![0f32; n];
    let mut t = 1.0f64;
    let (mut history, mut restarts, mut calm, mut iterations) = (Vec::new(), 0, Calm::default(), 0);
    let mut termination = Termination::MaxIterations;
    let mut f_x = f64::INFINITY;
    for k in 0..options.max_iterations {
        if cancel.load(Ordering::Relaxed) {
            termination = Termination::Cancelled;
            break;
        }
        let f_y = obj.value_and_gradient(&y, &mut grad);
        if !f_y.is_finite() {
            termination = Termination::NumericalFailure;
            break;
        }
        // Monotone: a step from y whose objective rose above f(x) is undone and the momentum dropped (a plain
        // projected-gradient step from x next).
        if f_y > f_x * (1.0 + 1e-12) && t > 1.0 {
            restarts += 1;
            t = 1.0;
            y.copy_from_slice(&x);
            continue;
        }
        // The projected gradient step from y, the restart test and the next extrapolated point, in one pass.
        let mut t_next = (1.0 + (1.0 + 4.0 * t * t).sqrt()) / 2.0;
        let beta = ((t - 1.0) / t_next) as f32;
        let uphill = fista_pass(
            &mut y,
            &grad,
            &x,
            &mut x_new,
            step,
            steps.as_deref(),
            beta,
            (lower, upper),
        );
        if uphill > 0.0 {
            // Gradient restart: momentum pointing uphill (⟨∇f(y), x⁺ − x⟩ > 0) is discarded: from t = 1, β = 0
            // and y is x⁺ itself.
            restarts += 1;
            t_next = (1.0 + 5f64.sqrt()) / 2.0;
            y.copy_from_slice(&x_new);
        }
        std::mem::swap(&mut x, &mut x_new);
        t = t_next;
        iterations = k + 1;
        let f_prev = f_x;
        f_x = f_y;
        history.push(f_y);
        progress(Progress {
            iteration: iterations,
            max_iterations: options.max_iterations,
            objective: f_y,
        });
        if calm.converged(f_prev, f_y, iterations, options) {
            termination = Termination::Converged;
            break;
        }
        if let Some(c) = checkpoint.as_mut() {
            if iterations % c.every == 0 && iterations < options.max_iterations && (c.stop)(iterations, &x) {
                termination = Termination::Stopped;
                break;
            }
        }
    }
    SolveResult {
        objective: obj.value(&x),
        x,
        history,
        iterations,
        restarts,
        lipschitz,
        termination,
        seconds: start.elapsed().as_secs_f64(),
    }
}

/// The stopping test of both solvers: |f_k − f_{k−1}| ≤ tolerance·|f_k| for `patience` consecutive iterations,
/// and not before `min_iterations` ([`SolverOptions`]).
#[derive(Default)]
struct Calm(u32);

impl Calm {
    /// Counts iteration `iterations` (objective `f`, the one before `f_prev`, infinite before the first) and
    /// answers whether the solve has converged.
    fn converged(&mut self, f_prev: f64, f: f64, iterations: u32, options: &SolverOptions) -> bool {
        if f_prev.is_finite() && (f_prev - f).abs() <= options.tolerance * f.abs().max(1e-30) {
            self.0 += 1;
            self.0 >= options.patience && iterations >= options.min_iterations
        } else {
            self.0 = 0;
            false
        }
    }
}

/// The unknowns per chunk of [`fista_pass`]: its partial sums are taken per chunk and added in the chunks' order,
/// so the restart test does not depend on how the work was split between threads.
const PASS_CHUNK: usize = 1 << 14;

/// [`fista_pass`]'s element-wise work on one chunk: x⁺ = Π(y − s·g), y ← Π(x⁺ + β(x⁺ − x)), s the unknown's step
/// in `steps` or `step` for all.
#[allow(clippy::too_many_arguments)]
fn step_chunk(
    y: &mut [f32],
    x_new: &mut [f32],
    g: &[f32],
    x: &[f32],
    step: f32,
    steps: Option<&[f32]>,
    beta: f32,
    project: &impl Fn(f32) -> f32,
) {
    let n = y.len();
    let (x_new, g, x) = (&mut x_new[..n], &g[..n], &x[..n]);
    match steps {
        Some(steps) => {
            let steps = &steps[..n];
            for k in 0..n {
                let v = project(y[k] - steps[k] * g[k]);
                y[k] = project(v + beta * (v - x[k]));
                x_new[k] = v;
            }
        }
        None => {
            for k in 0..n {
                let v = project(y[k] - step * g[k]);
                y[k] = project(v + beta * (v - x[k]));
                x_new[k] = v;
            }
        }
    }
}

/// ⟨g, a − b⟩ in f64, in eight running sums (added in order at the end), so that the additions overlap.
fn inner_difference(g: &[f32], a: &[f32], b: &[f32]) -> f64 {
    let mut lanes = [0f64; 8];
    let (gc, ac, bc) = (g.chunks_exact(8), a.chunks_exact(8), b.chunks_exact(8));
    let tail: f64 = (gc.remainder().iter().zip(ac.remainder()).zip(bc.remainder()))
        .map(|((g, a), b)| *g as f64 * (*a as f64 - *b as f64))
        .sum();
    for ((g, a), b) in gc.zip(ac).zip(bc) {
        for l in 0..8 {
            lanes[l] += g[l] as f64 * (a[l] as f64 - b[l] as f64);
        }
    }
    lanes.iter().sum::<f64>() + tail
}

/// Π onto [lower, upper]: `f32::clamp`'s arithmetic with its bounds checked once here, not per unknown (the
/// check kept the per-unknown passes from being vectorised).
fn box_projection(lower: f32, upper: f32) -> impl Fn(f32) -> f32 + Copy + Sync {
    assert!(lower <= upper, "the box's bounds, {lower} ≤ {upper}");
    move |v: f32| {
        let v = if v < lower { lower } else { v };
        if v > upper {
            upper
        } else {
            v
        }
    }
}

/// One FISTA iteration's vector work in one pass over the unknowns: x⁺ = Π(y − s∘∇f(y)) (s = `step` for every
/// unknown, or `steps`) into `x_new`; the restart test's ⟨∇f(y), x⁺ − x⟩ (returned, in f64); and the next
/// extrapolated point Π(x⁺ + β(x⁺ − x)) written over y, for the momentum kept (the caller recomputes y where the
/// test restarts). Three passes' arithmetic, element by element, with y, ∇f and x read once.
#[allow(clippy::too_many_arguments)]
pub fn fista_pass(
    y: &mut [f32],
    grad: &[f32],
    x: &[f32],
    x_new: &mut [f32],
    step: f32,
    steps: Option<&[f32]>,
    beta: f32,
    (lower, upper): (f32, f32),
) -> f64 {
    let project = box_projection(lower, upper);
    let chunk = |(i, (y, x_new)): (usize, (&mut [f32], &mut [f32]))| {
        let at = i * PASS_CHUNK;
        let (g, x) = (&grad[at..at + y.len()], &x[at..at + y.len()]);
        let steps = steps.map(|s| &s[at..at + y.len()]);
        step_chunk(y, x_new, g, x, step, steps, beta, &project);
        // The chunk is in cache now.
        inner_difference(g, x_new, x)
    };
    let partial: Vec<f64> = y
        .par_chunks_mut(PASS_CHUNK)
        .zip(x_new.par_chunks_mut(PASS_CHUNK))
        .enumerate()
        .map(chunk)
        .collect();
    partial.iter().sum()
}

/// The spectral projected gradient's memory: a trial step is accepted against the largest of the last
/// `SPG_MEMORY` objectives (the non-monotone line search of Grippo, Lampariello & Lucidi 1986).
const SPG_MEMORY: usize = 10;

/// Box-constrained minimisation by the spectral projected gradient (Birgin, Martínez & Raydan 2000, SPG2):
/// from x, the direction d = Π(x − α∇f(x)) − x with α the Barzilai–Borwein step ⟨s, s⟩/⟨s, y⟩ of the last move
/// (s = x_k − x_{k−1}, y = ∇f(x_k) − ∇f(x_{k−1}); for a quadratic, the inverse of the curvature's Rayleigh
/// quotient along s), x⁺ = x + λd with λ = 1 unless f(x⁺) exceeds max(last `SPG_MEMORY` objectives) +
/// 10⁻⁴·λ⟨∇f, d⟩, then λ from the safeguarded quadratic interpolation (kept in [0.1λ, 0.9λ], else λ/2). No
/// Lipschitz estimate: the first α is 1/‖Π(x − ∇f) − x‖∞ (the paper's choice). It stops as [`minimise`] does
/// (relative change of f for `patience` iterations, the cap, the cancel flag, a non-finite objective) or where
/// ⟨∇f, d⟩ ≥ 0 (x is stationary in the box). An alternative to FISTA measured by `eyekey bench --section
/// solver`; in its result `restarts` counts the line search's backtracks (each one objective evaluation more)
/// and `lipschitz` is 1/α of the last step.
pub fn minimise_spg(
    obj: &dyn Objective,
    x0: Vec<f32>,
    lower: f32,
    upper: f32,
    options: &SolverOptions,
    progress: &mut dyn FnMut(Progress),
    cancel: &AtomicBool,
) -> SolveResult {
    const ALPHA_MIN: f64 = 1e-30;
    const ALPHA_MAX: f64 = 1e30;
    let start = Instant::now();
    let n = obj.dim();
    assert_eq!(x0.len(), n, "warm start length");
    let project = box_projection(lower, upper);
    let mut x: Vec<f32> = x0.into_par_iter().map(project).collect();
    let mut g = vec![0f32; n];
    let mut f = obj.value_and_gradient(&x, &mut g);
    // `p` holds Π(x − α∇f), the end of the projected step; the direction is d = p − x.
    let (mut x_new, mut g_new, mut p) = (vec![0f32; n], vec![0f32; n], vec![0f32; n]);
    let largest_step = x
        .par_iter()
        .zip(g.par_iter())
        .map(|(xi, gi)| (project(xi - gi) - xi).abs() as f64)
        .reduce(|| 0.0, f64::max);
    let mut alpha = if largest_step > 0.0 {
        (1.0 / largest_step).clamp(ALPHA_MIN, ALPHA_MAX)
    } else {
        1.0
    };
    let mut recent = std::collections::VecDeque::from([f]);
    let (mut history, mut backtracks, mut calm, mut iterations) = (Vec::new(), 0u32, Calm::default(), 0u32);
    let mut termination = if f.is_finite() {
        Termination::MaxIterations
    } else {
        Termination::NumericalFailure
    };
    // No iteration from a non-finite start.
    let cap = if f.is_finite() { options.max_iterations } else { 0 };
    'iterations: for k in 0..cap {
        if cancel.load(Ordering::Relaxed) {
            termination = Termination::Cancelled;
            break;
        }
        // p = Π(x − α∇f) and ⟨∇f, p − x⟩, per chunk in f64 ([`inner_difference`]), added in the chunks' order.
        let a = alpha as f32;
        let slope: f64 = p
            .par_chunks_mut(PASS_CHUNK)
            .enumerate()
            .map(|(i, p)| {
                let at = i * PASS_CHUNK;
                let (x, g) = (&x[at..at + p.len()], &g[at..at + p.len()]);
                for ((pi, xi), gi) in p.iter_mut().zip(x).zip(g) {
                    *pi = project(xi - a * gi);
                }
                inner_difference(g, p, x)
            })
            .collect::<Vec<f64>>()
            .iter()
            .sum();
        if slope >= 0.0 {
            termination = Termination::Converged;
            break;
        }
        let reference = recent.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let mut lambda = 1.0f64;
        let f_new = loop {
            let l = lambda as f32;
            x_new
                .par_iter_mut()
                .zip(x.par_iter().zip(p.par_iter()))
                .for_each(|(xn, (xi, pi))| *xn = project(xi + l * (pi - xi)));
            let f_trial = obj.value_and_gradient(&x_new, &mut g_new);
            if !f_trial.is_finite() {
                termination = Termination::NumericalFailure;
                break 'iterations;
            }
            if f_trial <= reference + 1e-4 * lambda * slope {
                break f_trial;
            }
            backtracks += 1;
            if cancel.load(Ordering::Relaxed) {
                termination = Termination::Cancelled;
                break 'iterations;
            }
            let t = -0.5 * lambda * lambda * slope / (f_trial - f - lambda * slope);
            lambda = if t >= 0.1 * lambda && t <= 0.9 * lambda {
                t
            } else {
                0.5 * lambda
            };
        };
        // The Barzilai–Borwein step from s = x⁺ − x and y = ∇f(x⁺) − ∇f(x).
        let (ss, sy) = x_new
            .par_chunks(PASS_CHUNK)
            .enumerate()
            .map(|(i, xn)| {
                let at = i * PASS_CHUNK;
                let (x, g, gn) = (&x[at..at + xn.len()], &g[at..at + xn.len()], &g_new[at..at + xn.len()]);
                let (mut ss, mut sy) = (0f64, 0f64);
                for (((a, b), ga), gb) in xn.iter().zip(x).zip(g).zip(gn) {
                    let s = *a as f64 - *b as f64;
                    ss += s * s;
                    sy += s * (*gb as f64 - *ga as f64);
                }
                (ss, sy)
            })
            .collect::<Vec<(f64, f64)>>()
            .iter()
            .fold((0.0, 0.0), |acc, v| (acc.0 + v.0, acc.1 + v.1));
        alpha = if sy > 0.0 {
            (ss / sy).clamp(ALPHA_MIN, ALPHA_MAX)
        } else {
            ALPHA_MAX
        };
        std::mem::swap(&mut x, &mut x_new);
        std::mem::swap(&mut g, &mut g_new);
        let f_prev = f;
        f = f_new;
        if recent.len() == SPG_MEMORY {
            recent.pop_front();
        }
        recent.push_back(f);
        iterations = k + 1;
        history.push(f);
        progress(Progress {
            iteration: iterations,
            max_iterations: options.max_iterations,
            objective: f,
        });
        if calm.converged(f_prev, f, iterations, options) {
            termination = Termination::Converged;
            break;
        }
    }
    SolveResult {
        objective: f,
        x,
        history,
        iterations,
        restarts: backtracks,
        lipschitz: 1.0 / alpha,
        termination,
        seconds: start.elapsed().as_secs_f64(),
    }
}

/// Largest violation of the box-constrained first-order (KKT) conditions at x, relative to ‖∇f‖∞:
/// ∇f_i ≈ 0 inside, ≥ 0 at the lower bound, ≤ 0 at the upper bound.
pub fn kkt_violation(obj: &dyn Objective, x: &[f32], lower: f32, upper: f32) -> f64 {
    let mut g = vec![0f32; x.len()];
    obj.value_and_gradient(x, &mut g);
    let scale = g.iter().fold(0f64, |m, v| m.max(v.abs() as f64)).max(1e-30);
    let eps = 1e-6 * (upper - lower).abs().max(1.0);
    x.iter()
        .zip(&g)
        .map(|(xi, gi)| {
            let gi = *gi as f64;
            if *xi <= lower + eps {
                (-gi).max(0.0)
            } else if *xi >= upper - eps {
                gi.max(0.0)
            } else {
                gi.abs()
            }
        })
        .fold(0.0, f64::max)
        / scale
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// ‖M x − b‖² with a dense random M: small enough to solve independently.
    struct DenseLs {
        m: Vec<Vec<f64>>,
        b: Vec<f64>,
    }

    impl Objective for DenseLs {
        fn dim(&self) -> usize {
            self.m[0].len()
        }
        fn value_and_gradient(&self, x: &[f32], g: &mut [f32]) -> f64 {
            let r: Vec<f64> = self
                .m
                .iter()
                .zip(&self.b)
                .map(|(row, bi)| row.iter().zip(x).map(|(a, xi)| a * *xi as f64).sum::<f64>() - bi)
                .collect();
            for (j, gj) in g.iter_mut().enumerate() {
                *gj = (2.0 * self.m.iter().zip(&r).map(|(row, ri)| row[j] * ri).sum::<f64>()) as f32;
            }
            r.iter().map(|v| v * v).sum()
        }
    }

    fn problem(rows: usize, cols: usize, seed: u64) -> DenseLs {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let m = (0..rows)
            .map(|_| (0..cols).map(|_| rng.gen::<f64>() - 0.3).collect())
            .collect();
        let b = (0..rows).map(|_| 2.0 * rng.gen::<f64>() - 0.5).collect();
        DenseLs { m, b }
    }

    /// Independent solver: projected coordinate descent (Gauss–Seidel) in f64, run to full convergence.
    fn coordinate_descent(p: &DenseLs, lower: f64, upper: f64) -> Vec<f64> {
        let n = p.dim();
        let mut x = vec![0.0; n];
        let mut r: Vec<f64> = p.b.iter().map(|b| -b).collect();
        for _ in 0..20000 {
            for j in 0..n {
                let col: Vec<f64> = p.m.iter().map(|row| row[j]).collect();
                let cc: f64 = col.iter().map(|v| v * v).sum();
                let cr: f64 = col.iter().zip(&r).map(|(a, b)| a * b).sum();
                let new = (x[j] - cr / cc).clamp(lower, upper);
                let d = new - x[j];
                for (ri, ci) in r.iter_mut().zip(&col) {
                    *ri += d * ci;
                }
                x[j] = new;
            }
        }
        x
    }

    #[test]
    fn kkt_conditions_hold_and_an_independent_solver_agrees() {
        for preconditioned in [false, true] {
            kkt_and_agreement(preconditioned);
        }
    }

    /// Options that run a small problem to full convergence, in either metric.
    fn to_convergence(preconditioned: bool) -> SolverOptions {
        SolverOptions {
            max_iterations: 20000,
            tolerance: 1e-12,
            patience: 20,
            preconditioned,
            ..Default::default()
        }
    }

    fn kkt_and_agreement(preconditioned: bool) {
        let p = problem(40, 25, 3);
        let opts = to_convergence(preconditioned);
        let r = minimise(&p, vec![0.5; 25], 0.0, 1.0, &opts, &mut |_| {}, &AtomicBool::new(false));
        // f32 iterates: first-order conditions to 1e-3 of the gradient scale.
        assert!(
            kkt_violation(&p, &r.x, 0.0, 1.0) < 1e-3,
            "kkt {}",
            kkt_violation(&p, &r.x, 0.0, 1.0)
        );
        let reference = coordinate_descent(&p, 0.0, 1.0);
        let f_ref = {
            let xr: Vec<f32> = reference.iter().map(|v| *v as f32).collect();
            p.value(&xr)
        };
        // The problem is strictly convex (40 rows, 25 columns): same minimiser, same objective.
        assert!(
            (r.objective - f_ref).abs() <= 1e-4 * f_ref.abs().max(1.0),
            "{} vs {}",
            r.objective,
            f_ref
        );
        for (a, b) in r.x.iter().zip(&reference) {
            assert!((*a as f64 - b).abs() < 2e-3, "{a} vs {b}");
        }
        // Some bounds are active, so the box mattered.
        assert!(r.x.iter().any(|v| *v == 0.0 || *v == 1.0));
    }

    #[test]
    fn the_spectral_projected_gradient_finds_the_independent_solvers_minimiser() {
        for (p, dim) in [(problem(40, 25, 3), 25), (badly_scaled(40, 25, 4), 25)] {
            let opts = to_convergence(false);
            let r = minimise_spg(
                &p,
                vec![0.5; dim],
                0.0,
                1.0,
                &opts,
                &mut |_| {},
                &AtomicBool::new(false),
            );
            assert!(
                kkt_violation(&p, &r.x, 0.0, 1.0) < 1e-3,
                "kkt {}",
                kkt_violation(&p, &r.x, 0.0, 1.0)
            );
            let reference = coordinate_descent(&p, 0.0, 1.0);
            let xr: Vec<f32> = reference.iter().map(|v| *v as f32).collect();
            let f_ref = p.value(&xr);
            assert!(
                (r.objective - f_ref).abs() <= 1e-4 * f_ref.abs().max(1.0),
                "{} vs {f_ref}",
                r.objective
            );
            assert!(
                (r.objective - p.value(&r.x)).abs() <= 1e-9 * f_ref.abs().max(1.0),
                "the reported f is f(x)"
            );
            for (a, b) in r.x.iter().zip(&reference) {
                assert!((*a as f64 - b).abs() < 2e-3, "{a} vs {b}");
            }
            assert!(r.x.iter().any(|v| *v == 0.0 || *v == 1.0), "the box mattered");
        }
    }

    #[test]
    fn the_spectral_projected_gradient_takes_the_barzilai_borwein_step() {
        // f = Σ c_i (x_i − 2)² on [0, 10]: from x = 0 the first step 1/‖Π(x − ∇f) − x‖∞ = 1/10 (every
        // gradient −4c_i ≤ −4 clamps at 10); then s and y = 2c∘s give α = ⟨s, s⟩/⟨s, 2c∘s⟩ by hand.
        struct Diagonal(Vec<f64>);
        impl Objective for Diagonal {
            fn dim(&self) -> usize {
                self.0.len()
            }
            fn value_and_gradient(&self, x: &[f32], g: &mut [f32]) -> f64 {
                let mut f = 0.0;
                for ((xi, gi), c) in x.iter().zip(g.iter_mut()).zip(&self.0) {
                    let e = *xi as f64 - 2.0;
                    f += c * e * e;
                    *gi = (2.0 * c * e) as f32;
                }
                f
            }
        }
        let c = vec![1.0, 3.0];
        let opts = SolverOptions {
            max_iterations: 1,
            ..Default::default()
        };
        let r = minimise_spg(
            &Diagonal(c.clone()),
            vec![0.0; 2],
            0.0,
            10.0,
            &opts,
            &mut |_| {},
            &AtomicBool::new(false),
        );
        // First move: x = α·4c = (0.4, 1.2), accepted (f falls from 16 to 2.56 + 1.92 = 4.48).
        assert!((r.x[0] - 0.4).abs() < 1e-6 && (r.x[1] - 1.2).abs() < 1e-6, "{:?}", r.x);
        assert_eq!(r.restarts, 0);
        let s = [0.4f64, 1.2];
        let alpha = (s[0] * s[0] + s[1] * s[1]) / (2.0 * c[0] * s[0] * s[0] + 2.0 * c[1] * s[1] * s[1]);
        assert!(
            (1.0 / r.lipschitz - alpha).abs() < 1e-6 * alpha,
            "{} vs {alpha}",
            1.0 / r.lipschitz
        );
    }

    /// A non-negative least-squares problem whose columns differ in scale by 100×, as a light field's unknowns do
    /// (views seen by the target, by decoys only, by nobody).
    fn badly_scaled(rows: usize, cols: usize, seed: u64) -> DenseLs {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let scale: Vec<f64> = (0..cols).map(|j| 100f64.powf(j as f64 / (cols - 1) as f64)).collect();
        let m = (0..rows)
            .map(|_| scale.iter().map(|s| s * rng.gen::<f64>()).collect())
            .collect();
        let b = (0..rows).map(|_| 30.0 * rng.gen::<f64>()).collect();
        DenseLs { m, b }
    }

    #[test]
    fn jacobi_scales_are_the_inverse_curvature_row_sums() {
        // H = 2MᵀM for ‖Mx − b‖²; its row sums by hand, in f64.
        let p = badly_scaled(8, 5, 2);
        let s = jacobi_scales(&p);
        let top = (0..5)
            .map(|i| {
                (0..5)
                    .map(|j| 2.0 * p.m.iter().map(|row| row[i] * row[j]).sum::<f64>())
                    .sum::<f64>()
            })
            .collect::<Vec<f64>>();
        for (si, d) in s.iter().zip(&top) {
            assert!((*si as f64 * d - 1.0).abs() < 1e-4, "{si} vs 1/{d}");
        }
    }

    #[test]
    fn a_warm_start_on_a_changed_objective_runs_its_minimum_before_it_may_converge() {
        // Solved to the end, then one row's weight raised by half (a head-box round raising a stacked position):
        // from the old optimum the first steps move f by little against its size, and the tolerance test stops
        // the solve there, hardly moved; held to a minimum of iterations, it goes on towards the new optimum.
        // Columns 100× apart in scale, step 1/L: the raised row's pull lies along slow directions.
        let p = badly_scaled(80, 60, 6);
        let cancel = AtomicBool::new(false);
        let old = minimise(
            &p,
            vec![0.5; 60],
            0.0,
            1.0,
            &to_convergence(false),
            &mut |_| {},
            &cancel,
        );
        let mut changed = DenseLs {
            m: p.m.clone(),
            b: p.b.clone(),
        };
        let w = 1.5f64.sqrt();
        changed.m[0].iter_mut().for_each(|a| *a *= w);
        changed.b[0] *= w;
        let best = minimise(
            &changed,
            old.x.clone(),
            0.0,
            1.0,
            &to_convergence(false),
            &mut |_| {},
            &cancel,
        );
        let warm = |min_iterations: u32| {
            let opts = SolverOptions {
                max_iterations: 300,
                tolerance: 1e-5,
                min_iterations,
                ..Default::default()
            };
            minimise(&changed, old.x.clone(), 0.0, 1.0, &opts, &mut |_| {}, &cancel)
        };
        let (early, held) = (warm(0), warm(60));
        assert_eq!(early.termination, Termination::Converged);
        assert!(early.iterations < 60, "{}", early.iterations);
        assert!(held.iterations >= 60, "{}", held.iterations);
        // The gap to the new optimum (measured: 6.4e-4 at the start; 5.3e-4 after the early stop's 6 iterations,
        // 2.5e-4 after the held solve's 60).
        let gap = |r: &SolveResult| r.objective - best.objective;
        let start = changed.value(&old.x) - best.objective;
        assert!(gap(&early) > 0.75 * start, "early {} of {start}", gap(&early));
        assert!(
            gap(&held) < 0.5 * gap(&early),
            "held {} against {}",
            gap(&held),
            gap(&early)
        );
    }

    #[test]
    fn the_diagonal_metric_reaches_the_optimum_in_fewer_iterations_on_a_badly_scaled_problem() {
        let p = badly_scaled(80, 40, 7);
        let run = |preconditioned| {
            let opts = to_convergence(preconditioned);
            minimise(&p, vec![0.0; 40], 0.0, 1.0, &opts, &mut |_| {}, &AtomicBool::new(false))
        };
        let (plain, scaled) = (run(false), run(true));
        let f_star = plain.objective.min(scaled.objective);
        assert!(
            (plain.objective - scaled.objective).abs() <= 1e-5 * f_star,
            "{} vs {}",
            plain.objective,
            scaled.objective
        );
        let reached = |h: &[f64]| h.iter().position(|f| *f <= f_star * (1.0 + 1e-4)).expect("reached");
        let (a, b) = (reached(&plain.history), reached(&scaled.history));
        // Both in the box's interior and on its faces: the box mattered.
        assert!(scaled.x.iter().any(|v| *v == 0.0 || *v == 1.0));
        assert!(b * 3 <= a, "plain {a} iterations, preconditioned {b}");
    }

    #[test]
    fn objective_history_never_rises_much_and_progress_is_reported() {
        let p = problem(60, 30, 9);
        let mut calls = 0;
        let r = minimise(
            &p,
            vec![0.0; 30],
            0.0,
            1.0,
            &SolverOptions::default(),
            &mut |_| calls += 1,
            &AtomicBool::new(false),
        );
        assert_eq!(calls as u32, r.iterations);
        assert_eq!(r.history.len() as u32, r.iterations);
        assert!(r.history.last().unwrap() < &r.history[0]);
    }

    #[test]
    fn a_checkpoint_sees_every_nth_iterate_and_stops_the_solve_where_it_says() {
        let p = problem(60, 30, 9);
        let options = SolverOptions {
            max_iterations: 200,
            tolerance: 1e-12,
            ..Default::default()
        };
        let solve = |max_iterations: u32, checkpoint: Option<Checkpoint<'_>>| {
            let options = SolverOptions {
                max_iterations,
                ..options.clone()
            };
            minimise_judged(
                &p,
                vec![0.0; 30],
                0.0,
                1.0,
                &options,
                &mut |_| {},
                &AtomicBool::new(false),
                checkpoint,
            )
        };
        // Shown the iterates at 7, 14, …: each is the iterate of a solve capped there, bit for bit; told to stop
        // at 42, it ends there with that iterate.
        let mut seen = Vec::new();
        let mut stop = |k: u32, x: &[f32]| {
            seen.push((k, x.to_vec()));
            k == 42
        };
        let stopped = solve(
            200,
            Some(Checkpoint {
                every: 7,
                stop: &mut stop,
            }),
        );
        assert_eq!(stopped.termination, Termination::Stopped);
        assert_eq!(stopped.iterations, 42);
        assert_eq!(seen.iter().map(|s| s.0).collect::<Vec<_>>(), [7, 14, 21, 28, 35, 42]);
        for (k, x) in &seen {
            assert_eq!(*x, solve(*k, None).x, "the iterate at {k}");
        }
        let capped = solve(42, None);
        assert_eq!(capped.termination, Termination::MaxIterations);
        assert_eq!(stopped.x, capped.x);
        assert_eq!(stopped.history, capped.history);
        // A checkpoint that never says stop changes nothing, and is not asked after the last iteration.
        let mut asked = 0;
        let mut never = |_: u32, _: &[f32]| {
            asked += 1;
            false
        };
        let judged = solve(
            35,
            Some(Checkpoint {
                every: 7,
                stop: &mut never,
            }),
        );
        assert_eq!(asked, 4, "at 7, 14, 21 and 28; not at the cap, 35");
        let capped = solve(35, None);
        assert_eq!((judged.x, judged.termination), (capped.x, capped.termination));
    }

    #[test]
    fn cancel_stops_before_the_first_iteration() {
        let p = problem(10, 5, 1);
        let r = minimise(
            &p,
            vec![0.0; 5],
            0.0,
            1.0,
            &SolverOptions::default(),
            &mut |_| {},
            &AtomicBool::new(true),
        );
        assert_eq!(r.termination, Termination::Cancelled);
        assert_eq!(r.iterations, 0);
    }

    #[test]
    fn tridiagonal_top_eigenvalue_is_the_closed_form() {
        // tridiag(−1, 2, −1) of order n has eigenvalues 2 − 2cos(kπ/(n+1)), k = 1..n; the largest is k = n.
        for n in [1usize, 2, 5, 12, 40] {
            let a = vec![2.0; n];
            let b = vec![-1.0; n - 1];
            let exact = 2.0 - 2.0 * (n as f64 * std::f64::consts::PI / (n as f64 + 1.0)).cos();
            let got = tridiagonal_top_eigenvalue(&a, &b);
            assert!((got - exact).abs() < 1e-12, "n = {n}: {got} vs {exact}");
        }
        // A diagonal one: its largest entry.
        assert!((tridiagonal_top_eigenvalue(&[3.0, -1.0, 7.5, 2.0], &[0.0, 0.0, 0.0]) - 7.5).abs() < 1e-12);
    }

    #[test]
    fn lanczos_beats_the_power_iteration_and_stays_below_the_top_eigenvalue() {
        // ‖Mx − b‖²: curvature 2MᵀM. The truth and the power iteration's Rayleigh quotients in f64, from the
        // same start vector as the Lanczos estimate.
        // Zero-mean entries: a spread spectrum with a small top gap, where the power iteration is slow.
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let n = 24;
        let p = DenseLs {
            m: (0..60)
                .map(|_| (0..n).map(|_| rng.gen::<f64>() - 0.5).collect())
                .collect(),
            b: vec![0.0; 60],
        };
        let h = |v: &[f64]| -> Vec<f64> {
            let mv: Vec<f64> =
                p.m.iter()
                    .map(|row| row.iter().zip(v).map(|(a, b)| a * b).sum())
                    .collect();
            (0..n)
                .map(|j| 2.0 * p.m.iter().zip(&mv).map(|(row, m)| row[j] * m).sum::<f64>())
                .collect()
        };
        let mut v: Vec<f64> = start_vector(n, 12345).into_iter().map(f64::from).collect();
        let mut rayleigh = Vec::new();
        for _ in 0..2000 {
            let nv = v.iter().map(|a| a * a).sum::<f64>().sqrt();
            v.iter_mut().for_each(|a| *a /= nv);
            let w = h(&v);
            rayleigh.push(w.iter().zip(&v).map(|(a, b)| a * b).sum::<f64>());
            v = w;
        }
        let top = *rayleigh.last().unwrap();
        for k in [1u32, 2, 4, 8, 12] {
            let l = lanczos_top_eigenvalue(&p, k, 12345);
            let power = rayleigh[k as usize - 1];
            assert!(
                l >= power * (1.0 - 1e-5),
                "k = {k}: Lanczos {l} below the power iteration's {power}"
            );
            assert!(
                l <= top * (1.0 + 1e-5),
                "k = {k}: Lanczos {l} above the top eigenvalue {top}"
            );
        }
        // Twelve steps: within 10⁻⁴ of the top, and nearer than 12 power iterations.
        let l12 = lanczos_top_eigenvalue(&p, 12, 12345);
        assert!((top - l12) / top < 1e-4, "{l12} vs {top}");
        assert!(
            (top - rayleigh[11]) / top > (top - l12) / top,
            "{} vs {l12}",
            rayleigh[11]
        );
    }

    #[test]
    fn lipschitz_estimate_bounds_the_curvature() {
        // For ‖Mx − b‖², the curvature is 2MᵀM; its top eigenvalue by dense power iteration in f64.
        let p = problem(30, 12, 5);
        let n = 12;
        let mut v = vec![1.0f64; n];
        let mut lam = 0.0;
        for _ in 0..500 {
            let mv: Vec<f64> =
                p.m.iter()
                    .map(|row| row.iter().zip(&v).map(|(a, b)| a * b).sum())
                    .collect();
            let w: Vec<f64> = (0..n)
                .map(|j| 2.0 * p.m.iter().zip(&mv).map(|(row, m)| row[j] * m).sum::<f64>())
                .collect();
            lam = w.iter().zip(&v).map(|(a, b)| a * b).sum::<f64>() / v.iter().map(|a| a * a).sum::<f64>();
            let nw = w.iter().map(|a| a * a).sum::<f64>().sqrt();
            v = w.iter().map(|a| a / nw).collect();
        }
        let est = estimate_lipschitz(&p, 50, 1);
        assert!(est >= lam * 0.999 && est <= lam * 1.2, "{est} vs {lam}");
    }

    /// f(x) = Σ (a_i x_i − b_i)² + c Σ (x_i − x_(i+1))²: a chain long enough for several of the one-pass step's
    /// chunks, with targets outside the box so that bounds bind, and coupling enough for momentum to overshoot.
    struct Chain {
        a: Vec<f32>,
        b: Vec<f32>,
        c: f32,
    }

    impl Objective for Chain {
        fn dim(&self) -> usize {
            self.a.len()
        }
        fn value_and_gradient(&self, x: &[f32], g: &mut [f32]) -> f64 {
            let n = x.len();
            let mut f = 0f64;
            for i in 0..n {
                let r = self.a[i] * x[i] - self.b[i];
                f += (r as f64).powi(2);
                g[i] = 2.0 * self.a[i] * r;
            }
            for i in 0..n - 1 {
                let d = x[i] - x[i + 1];
                f += (self.c * d * d) as f64;
                g[i] += 2.0 * self.c * d;
                g[i + 1] -= 2.0 * self.c * d;
            }
            f
        }
    }

    /// The FISTA loop as three passes over the unknowns (the projected step, the restart test's inner product, the
    /// extrapolation), sequential: what [`fista_pass`] fuses, to compare its iterates with.
    fn three_pass_fista(
        obj: &dyn Objective,
        mut x: Vec<f32>,
        step: f32,
        steps: Option<&[f32]>,
        iterations: u32,
    ) -> (Vec<f32>, u32) {
        let project = |v: f32| v.clamp(0.0, 1.0);
        let n = x.len();
        let (mut y, mut x_new, mut grad) = (x.clone(), vec![0f32; n], vec![0f32; n]);
        let (mut t, mut f_x, mut restarts) = (1.0f64, f64::INFINITY, 0);
        for _ in 0..iterations {
            let f_y = obj.value_and_gradient(&y, &mut grad);
            for i in 0..n {
                x_new[i] = project(y[i] - steps.map_or(step, |s| s[i]) * grad[i]);
            }
            let uphill: f64 = (0..n).map(|i| grad[i] as f64 * (x_new[i] as f64 - x[i] as f64)).sum();
            let monotone_break = f_y > f_x * (1.0 + 1e-12) && t > 1.0;
            if uphill > 0.0 || monotone_break {
                restarts += 1;
                t = 1.0;
                if monotone_break {
                    y.copy_from_slice(&x);
                    continue;
                }
            }
            let t_next = (1.0 + (1.0 + 4.0 * t * t).sqrt()) / 2.0;
            let beta = ((t - 1.0) / t_next) as f32;
            for i in 0..n {
                y[i] = project(x_new[i] + beta * (x_new[i] - x[i]));
            }
            std::mem::swap(&mut x, &mut x_new);
            t = t_next;
            f_x = f_y;
        }
        (x, restarts)
    }

    #[test]
    fn the_one_pass_step_takes_the_three_pass_steps_bit_for_bit() {
        let n = 3 * PASS_CHUNK + 1234;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let chain = Chain {
            a: (0..n).map(|_| rng.gen_range(0.2f32..2.0)).collect(),
            b: (0..n).map(|_| rng.gen_range(-0.5f32..1.8)).collect(),
            c: 3.0,
        };
        let l = estimate_lipschitz(&chain, 30, 3);
        let scales = jacobi_scales(&chain);
        let x0: Vec<f32> = (0..n).map(|_| rng.gen::<f32>()).collect();
        for preconditioned in [false, true] {
            let l = if preconditioned {
                let half = scales.iter().map(|s| s.sqrt()).collect();
                estimate_lipschitz(&Scaled { inner: &chain, half }, 30, 3)
            } else {
                l
            };
            let opts = SolverOptions {
                max_iterations: 150,
                tolerance: 0.0,
                lipschitz: Some(l),
                preconditioned,
                ..Default::default()
            };
            let r = minimise(
                &chain,
                x0.clone(),
                0.0,
                1.0,
                &opts,
                &mut |_| {},
                &AtomicBool::new(false),
            );
            let step = (1.0 / l) as f32;
            let steps: Vec<f32> = scales.iter().map(|s| s * step).collect();
            let (x, restarts) = three_pass_fista(&chain, x0.clone(), step, preconditioned.then_some(&steps[..]), 150);
            assert!(
                r.restarts > 0,
                "the momentum restarts somewhere, so that both branches are compared"
            );
            assert_eq!(r.restarts, restarts, "preconditioned {preconditioned}");
            let differ = r.x.iter().zip(&x).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
            assert_eq!(differ, 0, "preconditioned {preconditioned}: {differ} unknowns differ");
            assert!(r.x.contains(&0.0) && r.x.contains(&1.0), "bounds bind");
        }
    }
}
