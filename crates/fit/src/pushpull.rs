//! Push-pull hole filling (Gortler et al. 1996, "The Lumigraph", sec. 3.3.1)
//! on the NDF table, periodic in azimuth.
//!
//! Pull: each coarser level holds the weighted mean of its 2x2 children,
//! with weight `min(1, sum of children's weights)`. Push: from coarse to
//! fine, a cell keeps `w v + (1 - w) v_parent`. Only cells inside the
//! observed region are written; nothing is extrapolated outside it.

/// Fill `values` (ring-major, `nt` rings of `np` sectors) where `weight < 1`
/// from the pyramid, for cells with `fill[c]` true.
pub fn push_pull(nt: usize, np: usize, values: &mut [f32], weight: &[f32], fill: &[bool]) {
    // Level 0 is the table itself: value and confidence in [0, 1].
    let mut levels: Vec<(usize, usize, Vec<f32>, Vec<f32>)> = Vec::new();
    let w0: Vec<f32> = weight.iter().map(|w| w.clamp(0.0, 1.0)).collect();
    levels.push((nt, np, values.to_vec(), w0));
    while {
        let (t, p, _, _) = &levels[levels.len() - 1];
        *t > 1 || *p > 2
    } {
        let (t, p, v, w) = &levels[levels.len() - 1];
        let (ct, cp) = (t.div_ceil(2), p.div_ceil(2).max(1));
        let mut cv = vec![0.0f32; ct * cp];
        let mut cw = vec![0.0f32; ct * cp];
        for a in 0..ct {
            for b in 0..cp {
                let (mut sw, mut swv) = (0.0f32, 0.0f32);
                for da in 0..2 {
                    for db in 0..2 {
                        let (ta, pb) = (2 * a + da, (2 * b + db) % p);
                        if ta >= *t {
                            continue;
                        }
                        let k = ta * p + pb;
                        sw += w[k];
                        swv += w[k] * v[k];
                    }
                }
                cv[a * cp + b] = if sw > 0.0 { swv / sw } else { 0.0 };
                cw[a * cp + b] = sw.min(1.0);
            }
        }
        levels.push((ct, cp, cv, cw));
        if ct == 1 && cp <= 2 {
            break;
        }
    }
    // Push back down, blending each level with its parent.
    for l in (0..levels.len() - 1).rev() {
        let (pt, pp) = (levels[l + 1].0, levels[l + 1].1);
        let parent = levels[l + 1].2.clone();
        let (t, p, v, w) = &mut levels[l];
        for a in 0..*t {
            for b in 0..*p {
                let k = a * *p + b;
                let pk = (a / 2).min(pt - 1) * pp + (b / 2).min(pp - 1);
                v[k] = w[k] * v[k] + (1.0 - w[k]) * parent[pk];
            }
        }
    }
    let filled = &levels[0].2;
    for c in 0..values.len() {
        if fill[c] && weight[c] < 1.0 {
            values[c] = filled[c];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fills_holes_with_neighbouring_values_and_leaves_the_rest() {
        let (nt, np) = (8, 16);
        let mut v = vec![0.0f32; nt * np];
        let mut w = vec![0.0f32; nt * np];
        for c in 0..nt * np {
            if c % 5 != 0 {
                v[c] = 2.0;
                w[c] = 1.0;
            }
        }
        let fill: Vec<bool> = (0..nt * np).map(|c| c < nt * np / 2).collect();
        push_pull(nt, np, &mut v, &w, &fill);
        for c in 0..nt * np {
            if c % 5 == 0 {
                if fill[c] {
                    assert!((v[c] - 2.0).abs() < 1e-4, "hole {c} filled with {}", v[c]);
                } else {
                    assert_eq!(v[c], 0.0, "cell {c} outside the region must stay empty");
                }
            } else {
                assert_eq!(v[c], 2.0);
            }
        }
    }
}
