//! IEEE 754 binary16 ("half") conversions on raw bits.
//!
//! PIPES carries f16 values as their 16 bits ([`crate::Value::F16`]). Every
//! f16 is exactly representable as an f32, so widening is exact; narrowing
//! succeeds only when the value is exactly an f16.

/// Widens f16 bits to the f32 of the same value (exact; NaNs stay NaN with
/// their payload shifted into the f32 mantissa).
pub fn f16_to_f32(h: u16) -> f32 {
    let negative = h & 0x8000 != 0;
    let sign = ((h & 0x8000) as u32) << 16;
    let exp = ((h >> 10) & 0x1f) as u32;
    let man = (h & 0x3ff) as u32;
    match exp {
        0 => {
            // Zero or subnormal: man × 2^-24, exact in f32.
            let v = man as f32 * (1.0 / 16_777_216.0);
            if negative {
                -v
            } else {
                v
            }
        }
        0x1f => f32::from_bits(sign | 0x7f80_0000 | (man << 13)),
        _ => f32::from_bits(sign | ((exp + 112) << 23) | (man << 13)),
    }
}

/// Widens f16 bits to the f64 of the same value (exact).
pub fn f16_to_f64(h: u16) -> f64 {
    f16_to_f32(h) as f64
}

/// The f16 bits of `x` if `x` is exactly an f16 value (infinities and zeros
/// of either sign included); any NaN becomes a quiet f16 NaN. `None` if `x`
/// is out of f16 range or would need rounding.
pub fn f32_to_f16_exact(x: f32) -> Option<u16> {
    let b = x.to_bits();
    let sign = ((b >> 16) & 0x8000) as u16;
    let exp = ((b >> 23) & 0xff) as i32;
    let man = b & 0x7f_ffff;
    if exp == 0xff {
        return Some(if man == 0 {
            sign | 0x7c00
        } else {
            sign | 0x7e00 | ((man >> 13) as u16 & 0x3ff)
        });
    }
    if exp == 0 {
        // f32 subnormals are far below the smallest f16 subnormal.
        return (man == 0).then_some(sign);
    }
    let e = exp - 127;
    if e > 15 {
        None
    } else if e >= -14 {
        // A normal f16: the low 13 mantissa bits must be zero.
        (man & 0x1fff == 0).then(|| sign | (((e + 15) as u16) << 10) | (man >> 13) as u16)
    } else if e >= -24 {
        // A subnormal f16: value = full × 2^(e-23) = m × 2^-24, m = full >> s.
        let full = man | 0x80_0000;
        let s = (-(e + 1)) as u32; // 14..=23
        (full & ((1u32 << s) - 1) == 0).then(|| sign | (full >> s) as u16)
    } else {
        None
    }
}

/// The f16 bits of `x` if `x` is exactly an f16 value; see [`f32_to_f16_exact`].
pub fn f64_to_f16_exact(x: f64) -> Option<u16> {
    f64_to_f32_exact(x).and_then(f32_to_f16_exact)
}

/// `x` as an f32 if that is exact (NaNs and infinities included).
pub fn f64_to_f32_exact(x: f64) -> Option<f32> {
    let f = x as f32;
    (x.is_nan() || f as f64 == x).then_some(f)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_values() {
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x7bff), 65504.0);
        assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24));
        assert_eq!(f16_to_f32(0x7c00), f32::INFINITY);
        assert!(f16_to_f32(0x7e00).is_nan());
        assert_eq!(f16_to_f32(0x8000).to_bits(), (-0.0f32).to_bits());
        assert_eq!(f32_to_f16_exact(0.1), None);
        assert_eq!(f32_to_f16_exact(65536.0), None);
        assert_eq!(f32_to_f16_exact(2f32.powi(-25)), None);
        assert_eq!(f32_to_f16_exact(0.5), Some(0x3800));
        assert_eq!(f64_to_f32_exact(0.1), None);
        assert_eq!(f64_to_f32_exact(0.5), Some(0.5));
    }

    #[test]
    fn every_f16_round_trips_through_f32() {
        for h in 0..=u16::MAX {
            let f = f16_to_f32(h);
            let back = f32_to_f16_exact(f).unwrap();
            if f.is_nan() {
                assert!(f16_to_f32(back).is_nan(), "{h:#06x}");
            } else {
                assert_eq!(back, h, "{h:#06x}");
            }
        }
    }

    #[test]
    fn f32_between_f16s_is_not_exact() {
        // Halfway between consecutive f16 values is never an f16.
        for h in 0..0x7bffu16 {
            let mid = (f16_to_f32(h) as f64 + f16_to_f32(h + 1) as f64) / 2.0;
            assert_eq!(f64_to_f16_exact(mid), None, "{h:#06x}");
        }
    }
}
