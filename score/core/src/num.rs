//! The number type of Score.
//!
//! The engine is generic over [`Real`] so that `f32` and `f64` builds can be measured side by side
//! (on a Cortex-M0+ without FPU both are soft-float; `f32` is roughly half the cost). The crate
//! feature `f32` selects which one the alias [`Num`] names; ports and the firmware use `Num`.

use core::fmt::{Debug, Display};
use core::ops::{Add, Div, Mul, Neg, Sub};

/// A floating-point type the engine can compute with (`f32` or `f64`).
pub trait Real:
    Copy
    + PartialEq
    + PartialOrd
    + Debug
    + Display
    + core::fmt::LowerExp
    + Default
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + 'static
{
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// 0.5 (halving by multiplication is exact and, in soft float, cheaper than dividing).
    const HALF: Self;
    /// Not a number.
    const NAN: Self;
    /// Machine epsilon (distance from 1 to the next representable value).
    const EPSILON: Self;
    /// Name of the type, for reports.
    const NAME: &'static str;
    /// Nearest value of this type.
    fn from_f64(v: f64) -> Self;
    /// Exact widening (or identity).
    fn to_f64(self) -> f64;
    /// Nearest value to `v`.
    fn from_u32(v: u32) -> Self;
    /// Seconds from a duration in microseconds (`us / 1e6`, one rounding).
    fn seconds_from_us(us: u64) -> Self;
    /// Parses a finite decimal number; `inf`/`nan` are refused.
    fn parse_finite(s: &str) -> Option<Self>;
    /// Square root.
    fn sqrt(self) -> Self;
    /// Sine.
    fn sin(self) -> Self;
    /// Cosine.
    fn cos(self) -> Self;
    /// e to the power of `self`.
    fn exp(self) -> Self;
    /// Absolute value.
    fn abs(self) -> Self;
    /// Neither infinite nor NaN.
    fn is_finite(self) -> bool;
    /// `self * 0.5`, the same bits in every case.
    #[inline]
    fn halve(self) -> Self {
        self * Self::HALF
    }
}

macro_rules! impl_real {
    ($t:ty, $name:literal, $sqrt:path, $sin:path, $cos:path, $exp:path, $fabs:path,
     $bits:ty, $mant_bits:literal, $exp_max:literal) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            const HALF: Self = 0.5;
            const NAN: Self = <$t>::NAN;
            const EPSILON: Self = <$t>::EPSILON;
            const NAME: &'static str = $name;
            #[inline]
            fn from_f64(v: f64) -> Self {
                v as $t
            }
            #[inline]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline]
            fn from_u32(v: u32) -> Self {
                v as $t
            }
            #[inline]
            fn seconds_from_us(us: u64) -> Self {
                us as $t / 1.0e6
            }
            fn parse_finite(s: &str) -> Option<Self> {
                // Rust also accepts "inf", "NaN" and "infinity"; Score wants plain decimals.
                let digits = s.trim_start_matches(['+', '-']);
                if !digits.starts_with(|c: char| c.is_ascii_digit() || c == '.') {
                    return None;
                }
                s.parse::<$t>().ok().filter(|v| v.is_finite())
            }
            #[inline]
            fn sqrt(self) -> Self {
                $sqrt(self)
            }
            #[inline]
            fn sin(self) -> Self {
                $sin(self)
            }
            #[inline]
            fn cos(self) -> Self {
                $cos(self)
            }
            #[inline]
            fn exp(self) -> Self {
                $exp(self)
            }
            #[inline]
            fn abs(self) -> Self {
                $fabs(self)
            }
            #[inline]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
            /// A normal number whose half is normal is halved exactly by decrementing its
            /// exponent: a few integer instructions instead of a soft-float multiplication
            /// (hundreds of cycles for f64 on a Cortex-M0+). Zeros, subnormals, the smallest
            /// exponent (whose half rounds), infinities and NaNs take the multiplication.
            #[inline]
            fn halve(self) -> Self {
                // Out of line: otherwise LLVM computes the (soft-float) product on every call
                // and selects.
                #[cold]
                #[inline(never)]
                fn multiply(x: $t) -> $t {
                    x * 0.5
                }
                let b = self.to_bits();
                let e = (b >> $mant_bits) & $exp_max;
                if (2..$exp_max).contains(&e) {
                    <$t>::from_bits(b - (1 << $mant_bits))
                } else {
                    multiply(self)
                }
            }
        }
    };
}

impl_real!(
    f32,
    "f32",
    libm::sqrtf,
    libm::sinf,
    libm::cosf,
    libm::expf,
    libm::fabsf,
    u32,
    23,
    0xff
);
impl_real!(
    f64,
    "f64",
    libm::sqrt,
    libm::sin,
    libm::cos,
    libm::exp,
    libm::fabs,
    u64,
    52,
    0x7ff
);

/// Shortest text that reads back as the same value: plain decimals for ordinary magnitudes,
/// exponent form (`1.5e-9`) for very small or large ones so a line stays short (logs, `save`).
pub struct Compact<N>(pub N);

impl<N: Real> core::fmt::Display for Compact<N> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let a = self.0.abs().to_f64();
        if a == 0.0 || (1e-5..1e15).contains(&a) || !a.is_finite() {
            write!(f, "{}", self.0)
        } else {
            write!(f, "{:e}", self.0)
        }
    }
}

/// The number type selected for this build: `f64` by default, `f32` with the `f32` feature.
#[cfg(not(feature = "f32"))]
pub type Num = f64;
/// The number type selected for this build: `f64` by default, `f32` with the `f32` feature.
#[cfg(feature = "f32")]
pub type Num = f32;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parse_refuses_non_finite_and_words() {
        for bad in [
            "inf", "-inf", "NaN", "infinity", "", "-", "1e999", "abc", "1.2.3",
        ] {
            assert_eq!(f64::parse_finite(bad), None, "{bad}");
        }
        assert_eq!(f64::parse_finite("-.5"), Some(-0.5));
        assert_eq!(f64::parse_finite("1e-3"), Some(1e-3));
        assert_eq!(f32::parse_finite("0.0788"), Some(0.0788f32));
    }

    #[test]
    fn compact_text_reads_back_exactly() {
        extern crate std;
        use std::string::ToString;
        for v in [0.0, -1.5, 0.0788, 1e-300, -2.5e20, 123456.789, 1.0 / 3.0] {
            let t = Compact(v).to_string();
            assert!(t.len() <= 24, "{t}");
            assert_eq!(t.parse::<f64>().unwrap(), v);
        }
        assert_eq!(Compact(1e-9f32).to_string(), "1e-9");
    }

    /// `halve` must be `x * 0.5` bit for bit: the edges of every exponent range and a
    /// spread of bit patterns over the whole space (signs, subnormals, infinities, NaNs).
    #[test]
    fn halve_is_multiplication_by_one_half() {
        fn same<T: Real>(x: T, bits: impl Fn(T) -> u64) {
            let (h, m) = (x.halve(), x * T::HALF);
            assert!(
                bits(h) == bits(m) || (h != h && m != m),
                "{x:e}: {h:e} vs {m:e}"
            );
        }
        let f32_edges = [
            0.0f32,
            -0.0,
            1.0,
            -1.0,
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
            f32::MIN_POSITIVE * 2.0,
            f32::MIN_POSITIVE * 3.0,
            1e-45,
            3e-45,
            f32::MAX,
            f32::MIN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            f32::EPSILON,
        ];
        let f64_edges = [
            0.0f64,
            -0.0,
            1.0,
            -1.0,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            f64::MIN_POSITIVE * 2.0,
            f64::MIN_POSITIVE * 3.0,
            5e-324,
            1.5e-323,
            f64::MAX,
            f64::MIN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
            f64::EPSILON,
        ];
        for x in f32_edges {
            same(x, |v| v.to_bits() as u64);
        }
        for x in f64_edges {
            same(x, f64::to_bits);
        }
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..200_000 {
            s = s
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            same(f64::from_bits(s), f64::to_bits);
            same(f32::from_bits((s >> 32) as u32), |v| v.to_bits() as u64);
        }
    }

    #[test]
    fn seconds_from_us_is_one_rounding() {
        assert_eq!(f64::seconds_from_us(10_000), 0.01);
        assert_eq!(f32::seconds_from_us(1_000), 0.001f32);
    }
}
