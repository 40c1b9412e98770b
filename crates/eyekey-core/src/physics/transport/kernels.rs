//! The fused multi-band sparse products (hand-written: no sparse crate fuses the spectral coupling into the product with this layout).

use rayon::prelude::*;

/// Rows per rayon task in the sparse kernels: about eight tasks per thread (enough to balance rows of
/// uneven length), but never fewer than 64 rows (scheduling must stay cheap).
pub(crate) fn rows_per_task(n_rows: usize) -> usize {
    (n_rows / (8 * rayon::current_num_threads().max(1))).max(64)
}

/// out[r·3 + a] = Σ_n c[n][a] Σ_e v_e · x[col_e · N + n] (forward, Eq. 13), or with `transpose_mix`
/// out[r·N + n] = Σ_a c[n][a] Σ_e v_e · y[col_e · 3 + a] (adjoint): the sparse product fused with the spectral
/// coupling. Dispatches to a version specialised on the input width for the common 3- and 4-band cases.
#[allow(clippy::too_many_arguments)]
pub(crate) fn spmv_fused(
    indptr: &[u32],
    indices: &[u32],
    values: &[f32],
    x: &[f32],
    n_in: usize,
    mix: &[[f32; 3]],
    transpose_mix: bool,
    out: &mut [f32],
    n_out: usize,
) {
    debug_assert!(n_in <= 16 && n_out <= 16);
    match n_in {
        3 => spmv_fixed::<3>(indptr, indices, values, x, mix, transpose_mix, out, n_out),
        4 => spmv_fixed::<4>(indptr, indices, values, x, mix, transpose_mix, out, n_out),
        _ => spmv_fixed::<16>(indptr, indices, values, x, mix, transpose_mix, out, n_out),
    }
}

/// The kernel for an input width of at most `NI` (exactly `NI` when NI < 16; `x.len() / n_cols` otherwise).
#[allow(clippy::too_many_arguments)]
pub(crate) fn spmv_fixed<const NI: usize>(
    indptr: &[u32],
    indices: &[u32],
    values: &[f32],
    x: &[f32],
    mix: &[[f32; 3]],
    transpose_mix: bool,
    out: &mut [f32],
    n_out: usize,
) {
    let n_in = if NI < 16 {
        NI
    } else if transpose_mix {
        3
    } else {
        mix.len()
    };
    let rows_per_chunk = rows_per_task(out.len() / n_out.max(1));
    out.par_chunks_mut(rows_per_chunk * n_out)
        .enumerate()
        .for_each(|(chunk, out_rows)| {
            let first = chunk * rows_per_chunk;
            for (k, o) in out_rows.chunks_exact_mut(n_out).enumerate() {
                let r = first + k;
                let mut acc = [0f32; NI];
                let (a, b) = (indptr[r] as usize, indptr[r + 1] as usize);
                // Two independent accumulators over alternating entries hide the FMA latency.
                let mut acc2 = [0f32; NI];
                let (idx, val) = (&indices[a..b], &values[a..b]);
                let pairs = idx.len() / 2;
                for p in 0..pairs {
                    let (i0, i1) = (idx[2 * p] as usize * n_in, idx[2 * p + 1] as usize * n_in);
                    let (v0, v1) = (val[2 * p], val[2 * p + 1]);
                    let (x0, x1) = (&x[i0..i0 + n_in], &x[i1..i1 + n_in]);
                    for ((s0, s1), (a0, a1)) in acc.iter_mut().zip(acc2.iter_mut()).zip(x0.iter().zip(x1)) {
                        *s0 += v0 * a0;
                        *s1 += v1 * a1;
                    }
                }
                if idx.len() % 2 == 1 {
                    let i0 = idx[idx.len() - 1] as usize * n_in;
                    let v0 = val[val.len() - 1];
                    for (s0, a0) in acc.iter_mut().zip(&x[i0..i0 + n_in]) {
                        *s0 += v0 * a0;
                    }
                }
                for (s0, s1) in acc.iter_mut().zip(acc2) {
                    *s0 += s1;
                }
                if transpose_mix {
                    // Adjoint: out_n = Σ_a c[n][a] acc_a.
                    for (slot, m) in o.iter_mut().zip(mix) {
                        *slot = m[0] * acc[0] + m[1] * acc[1] + m[2] * acc[2];
                    }
                } else {
                    // Forward: out_a = Σ_n c[n][a] acc_n.
                    for (a, slot) in o.iter_mut().enumerate() {
                        *slot = mix.iter().zip(&acc).map(|(m, v)| m[a] * v).sum();
                    }
                }
            }
        });
}

/// One band of a band-dependent operator (wave optics): out[r·3 + a] (+)= c[a] Σ_e v_e · x[col_e · N + n]
/// for band n of an N-band light field; with `accumulate` the products are added to `out`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn spmv_band_forward(
    indptr: &[u32],
    indices: &[u32],
    values: &[f32],
    x: &[f32],
    n_bands: usize,
    band: usize,
    c: [f32; 3],
    accumulate: bool,
    out: &mut [f32],
) {
    let rows_per_chunk = rows_per_task(out.len() / 3);
    out.par_chunks_mut(rows_per_chunk * 3)
        .enumerate()
        .for_each(|(chunk, out_rows)| {
            let first = chunk * rows_per_chunk;
            for (k, o) in out_rows.chunks_exact_mut(3).enumerate() {
                let r = first + k;
                let (a, b) = (indptr[r] as usize, indptr[r + 1] as usize);
                let (mut s0, mut s1) = (0f32, 0f32);
                let (idx, val) = (&indices[a..b], &values[a..b]);
                let pairs = idx.len() / 2;
                for p in 0..pairs {
                    s0 += val[2 * p] * x[idx[2 * p] as usize * n_bands + band];
                    s1 += val[2 * p + 1] * x[idx[2 * p + 1] as usize * n_bands + band];
                }
                if idx.len() % 2 == 1 {
                    s0 += val[val.len() - 1] * x[idx[idx.len() - 1] as usize * n_bands + band];
                }
                let s = s0 + s1;
                for (slot, ca) in o.iter_mut().zip(c) {
                    *slot = if accumulate { *slot + ca * s } else { ca * s };
                }
            }
        });
}

/// The adjoint of [`spmv_band_forward`] on Tᵀ's rows: out[p·N + n] = Σ_a c[a] Σ_e v_e · y[col_e · 3 + a]; the
/// other bands' entries of `out` are left as they are.
#[allow(clippy::too_many_arguments)]
pub(crate) fn spmv_band_adjoint(
    indptr: &[u32],
    indices: &[u32],
    values: &[f32],
    y: &[f32],
    c: [f32; 3],
    n_bands: usize,
    band: usize,
    out: &mut [f32],
) {
    let rows_per_chunk = rows_per_task(out.len() / n_bands);
    out.par_chunks_mut(rows_per_chunk * n_bands)
        .enumerate()
        .for_each(|(chunk, out_rows)| {
            let first = chunk * rows_per_chunk;
            for (k, o) in out_rows.chunks_exact_mut(n_bands).enumerate() {
                let r = first + k;
                let (a, b) = (indptr[r] as usize, indptr[r + 1] as usize);
                let mut acc = [0f32; 3];
                for (&i, &v) in indices[a..b].iter().zip(&values[a..b]) {
                    let yi = &y[i as usize * 3..i as usize * 3 + 3];
                    acc[0] += v * yi[0];
                    acc[1] += v * yi[1];
                    acc[2] += v * yi[2];
                }
                o[band] = c[0] * acc[0] + c[1] * acc[1] + c[2] * acc[2];
            }
        });
}
