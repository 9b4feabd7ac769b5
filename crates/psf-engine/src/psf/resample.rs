//! Resampling a finely sampled intensity onto a detector grid: each output pixel gets the
//! exact integral of the bilinear interpolant of the native samples over its area, so the
//! result is energy-preserving for any output pitch, coarser or finer than the native one.

/// Integral of the unit hat function max(0, 1 - |u|) over [lo, hi].
fn hat_integral(lo: f64, hi: f64) -> f64 {
    let prim = |u: f64| -> f64 {
        // Antiderivative of the hat, 0 at u = -1, 1 at u = 1.
        let u = u.clamp(-1.0, 1.0);
        if u <= 0.0 {
            0.5 * (1.0 + u) * (1.0 + u)
        } else {
            1.0 - 0.5 * (1.0 - u) * (1.0 - u)
        }
    };
    prim(hi) - prim(lo)
}

/// Sparse weights w[c] = [(native index, weight)] mapping native samples at
/// x_m = (m - native_centre) * native_pitch to output pixels centred at
/// (c - out_centre) * out_pitch with width out_pitch. Weights carry units of length.
pub fn weights_1d(
    native_len: usize,
    native_pitch: f64,
    native_centre: f64,
    out_len: usize,
    out_pitch: f64,
    out_centre: f64,
) -> Vec<Vec<(usize, f64)>> {
    (0..out_len)
        .map(|c| {
            let x0 = (c as f64 - out_centre - 0.5) * out_pitch;
            let x1 = x0 + out_pitch;
            // Native samples whose hats overlap [x0, x1].
            let m0 = ((x0 / native_pitch + native_centre).floor() as i64 - 1).max(0);
            let m1 = ((x1 / native_pitch + native_centre).ceil() as i64 + 1).min(native_len as i64 - 1);
            let mut w = vec![];
            for m in m0..=m1 {
                let xm = (m as f64 - native_centre) * native_pitch;
                let v = hat_integral((x0 - xm) / native_pitch, (x1 - xm) / native_pitch) * native_pitch;
                if v > 0.0 {
                    w.push((m as usize, v));
                }
            }
            w
        })
        .collect()
}

/// Keys cubic-convolution kernel (a = -0.5): interpolates samples with O(h^3) error.
fn keys(t: f64) -> f64 {
    let t = t.abs();
    if t < 1.0 {
        1.5 * t * t * t - 2.5 * t * t + 1.0
    } else if t < 2.0 {
        -0.5 * t * t * t + 2.5 * t * t - 4.0 * t + 2.0
    } else {
        0.0
    }
}

/// Point-sampling weights: the cubic interpolant of the native samples evaluated at each
/// output pixel centre, times the output pitch (so values carry units of length, like
/// `weights_1d`, and a 2-D product gives intensity x pixel area).
pub fn point_weights_1d(
    native_len: usize,
    native_pitch: f64,
    native_centre: f64,
    out_len: usize,
    out_pitch: f64,
    out_centre: f64,
) -> Vec<Vec<(usize, f64)>> {
    (0..out_len)
        .map(|c| {
            let u = (c as f64 - out_centre) * out_pitch / native_pitch + native_centre;
            let m0 = u.floor() as i64;
            (m0 - 1..=m0 + 2)
                .filter(|&m| m >= 0 && (m as usize) < native_len)
                .map(|m| (m as usize, keys(u - m as f64) * out_pitch))
                .filter(|&(_, w)| w != 0.0)
                .collect()
        })
        .collect()
}

/// out[r][c] = sum_n sum_m wy[r][n] wx[c][m] native[n][m] (row-major native, `nx` columns).
/// Separable: first along x for every native row that wy reads, then along y.
pub fn apply(native: &[f64], nx: usize, wy: &[Vec<(usize, f64)>], wx: &[Vec<(usize, f64)>]) -> Vec<f64> {
    let (oy, ox) = (wy.len(), wx.len());
    let mut out = vec![0.0; oy * ox];
    let (lo, hi) = wy
        .iter()
        .flatten()
        .fold((usize::MAX, 0), |(lo, hi), &(n, _)| (lo.min(n), hi.max(n)));
    if lo > hi {
        return out;
    }
    // tmp[n - lo][c] = sum_m wx[c][m] native[n][m]
    let mut tmp = vec![0.0; (hi - lo + 1) * ox];
    for (t, n) in tmp.chunks_exact_mut(ox).zip(lo..=hi) {
        let src = &native[n * nx..(n + 1) * nx];
        for (v, wc) in t.iter_mut().zip(wx) {
            let mut acc = 0.0;
            for &(m, wm) in wc {
                acc += wm * src[m];
            }
            *v = acc;
        }
    }
    for (row, wr) in out.chunks_exact_mut(ox).zip(wy) {
        for &(n, wn) in wr {
            for (v, t) in row.iter_mut().zip(&tmp[(n - lo) * ox..(n - lo + 1) * ox]) {
                *v += wn * t;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_preserve_energy_of_a_smooth_function() {
        // Gaussian sampled at pitch 0.1, resampled to pitch 0.37 and 0.05.
        let f = |x: f64| (-x * x / 2.0).exp();
        let native: Vec<f64> = (0..401).map(|m| f((m as f64 - 200.0) * 0.1)).collect();
        let total: f64 = native.iter().sum::<f64>() * 0.1;
        for (pitch, len) in [(0.37, 60usize), (0.05, 400)] {
            let w = weights_1d(401, 0.1, 200.0, len, pitch, len as f64 / 2.0);
            let out: f64 = w
                .iter()
                .map(|ws| ws.iter().map(|&(m, v)| v * native[m]).sum::<f64>())
                .sum();
            assert!((out - total).abs() < 1e-9 * total, "{out} vs {total}");
        }
    }
}
