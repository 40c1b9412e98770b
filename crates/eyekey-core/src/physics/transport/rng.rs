//! SplitMix64, the seedable generator of the sub-ray jitter, and the low-discrepancy sequence the kernels'
//! sub-rays are drawn from.

use super::SubRaySequence;

/// SplitMix64 (Steele, Lea & Flood 2014): a tiny, fast, seedable generator for the sub-ray jitter.
pub(crate) struct SplitMix64(pub(crate) u64);

impl SplitMix64 {
    pub(crate) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub(crate) fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

/// The dimensions of one kernel sub-ray: its point in the aperture (2), in the screen pixel (2) and its
/// diffraction angle (2).
pub(crate) const SUB_RAY_DIMS: usize = 6;

/// The generators of the R₆ Kronecker sequence (Roberts 2018, "The unreasonable effectiveness of quasirandom
/// sequences"): αᵢ = φ₆^−(i+1) mod 1, with φ₆ the positive root of x⁷ = x + 1 (the generalised golden ratio).
fn r6_alpha() -> [f64; SUB_RAY_DIMS] {
    static ALPHA: std::sync::OnceLock<[f64; SUB_RAY_DIMS]> = std::sync::OnceLock::new();
    *ALPHA.get_or_init(|| {
        let d = SUB_RAY_DIMS as i32;
        let mut g = 1.1f64;
        for _ in 0..60 {
            g -= (g.powi(d + 1) - g - 1.0) / ((d + 1) as f64 * g.powi(d) - 1.0);
        }
        std::array::from_fn(|i| g.powi(-(i as i32 + 1)).fract())
    })
}

/// One (view, block)'s sub-ray draws. With [`SubRaySequence::Kronecker`] the n-th sub-ray's six uniforms are
/// the n-th point of the R₆ sequence shifted by a random vector drawn once from the seed (a Cranley–Patterson
/// rotation): each point is uniform on [0, 1)⁶, so every kernel stays an unbiased estimate, and the points of
/// one block fill the cube evenly, so the kernel's sampling noise falls faster than with independent draws
/// ([`SubRaySequence::Independent`], SplitMix64).
pub(crate) struct SubRayDraws {
    alpha: [f64; SUB_RAY_DIMS],
    shift: [f64; SUB_RAY_DIMS],
    n: u64,
    random: Option<SplitMix64>,
}

impl SubRayDraws {
    pub(crate) fn new(seed: u64, sequence: SubRaySequence) -> Self {
        let mut rng = SplitMix64(seed);
        let shift: [f64; SUB_RAY_DIMS] = std::array::from_fn(|_| rng.next_f64());
        let random = (sequence == SubRaySequence::Independent).then_some(rng);
        Self {
            alpha: r6_alpha(),
            shift,
            n: 0,
            random,
        }
    }

    /// The next sub-ray's six uniforms in [0, 1).
    pub(crate) fn next_ray(&mut self) -> [f64; SUB_RAY_DIMS] {
        if let Some(rng) = &mut self.random {
            return std::array::from_fn(|_| rng.next_f64());
        }
        let n = self.n as f64;
        self.n += 1;
        std::array::from_fn(|i| (self.shift[i] + n * self.alpha[i]).fract())
    }

    /// The next `len` (≤ [`RAY_BATCH`]) sub-rays' first `D` uniforms, dimension by dimension (`out[i][k]` is
    /// the k-th sub-ray's i-th; the remaining dimensions are drawn and dropped, as [`Self::next_ray`] would):
    /// the values `len` calls of [`Self::next_ray`] give, bit for bit, in loops the compiler vectorises.
    pub(crate) fn next_batch<const D: usize>(&mut self, len: usize, out: &mut [[f64; RAY_BATCH]; D]) {
        assert!(len <= RAY_BATCH && D <= SUB_RAY_DIMS);
        if self.random.is_some() || self.n + (RAY_BATCH as u64) >= 1 << 30 {
            for k in 0..len {
                let r = self.next_ray();
                for (i, dim) in out.iter_mut().enumerate() {
                    dim[k] = r[i];
                }
            }
            return;
        }
        let base = self.n as f64;
        for (i, dim) in out.iter_mut().enumerate() {
            let (shift, alpha) = (self.shift[i], self.alpha[i]);
            for (v, k) in dim.iter_mut().zip(&BATCH_INDEX).take(len) {
                // (shift + n·α).fract(): n < 2³⁰ and shift, α in [0, 1), so x is finite in [0, 2³¹) and its
                // truncation is the integer cast's.
                let x = shift + (base + k) * alpha;
                // SAFETY: x is finite and in [0, 2³¹) (above), within i32.
                *v = x - unsafe { x.to_int_unchecked::<i32>() } as f64;
            }
        }
        self.n += len as u64;
    }
}

/// The sub-rays [`SubRayDraws::next_batch`] draws at most at once.
pub(crate) const RAY_BATCH: usize = 64;

/// 0, 1, …, `RAY_BATCH` − 1 as floats.
const BATCH_INDEX: [f64; RAY_BATCH] = {
    let mut a = [0.0; RAY_BATCH];
    let mut k = 0;
    while k < RAY_BATCH {
        a[k] = k as f64;
        k += 1;
    }
    a
};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_batch_is_the_sub_rays_one_at_a_time_bit_for_bit() {
        for sequence in [SubRaySequence::Kronecker, SubRaySequence::Independent] {
            let (mut one, mut batch) = (SubRayDraws::new(77, sequence), SubRayDraws::new(77, sequence));
            // Past the first batch, with a short one between, and far along the sequence.
            batch.n = 1_000_000;
            one.n = 1_000_000;
            for len in [RAY_BATCH, 13, RAY_BATCH, 1] {
                let mut out = [[0.0; RAY_BATCH]; 4];
                batch.next_batch(len, &mut out);
                for k in 0..len {
                    let r = one.next_ray();
                    for (i, dim) in out.iter().enumerate() {
                        assert_eq!(
                            dim[k].to_bits(),
                            r[i].to_bits(),
                            "{sequence:?} len {len} ray {k} dim {i}"
                        );
                        assert!((0.0..1.0).contains(&dim[k]));
                    }
                }
            }
            assert_eq!(one.next_ray(), batch.next_ray());
        }
    }
}
