//! Choice parameters: an enum whose variants each have one manifest name. The names are
//! written once, in the [`choices!`](crate::choices) invocation beside the enum; parsing
//! ([`FromStr`](core::str::FromStr)), printing and the list the validator and the reference
//! show all come from there, so a name cannot be accepted by one and unknown to another, and
//! no builder falls back to a default for a name it does not know.

/// An enum chosen by name in the manifest.
pub trait Choice: Copy + core::str::FromStr<Err = UnknownChoice> + 'static {
    /// Every accepted name, in declaration order.
    const NAMES: &'static [&'static str];
    /// The manifest name of this value.
    fn name(self) -> &'static str;
}

/// A name that is none of a choice's.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{value:?} is not one of: {}", .choices.join(", "))]
pub struct UnknownChoice {
    /// What was given.
    pub value: String,
    /// What is accepted.
    pub choices: &'static [&'static str],
}

/// Implements [`Choice`], `FromStr` and `Display` for a field-less enum from one table of
/// `Variant = "name"` pairs.
#[macro_export]
macro_rules! choices {
    ($ty:ty { $($variant:ident = $name:literal),+ $(,)? }) => {
        impl $crate::kinds::Choice for $ty {
            const NAMES: &'static [&'static str] = &[$($name),+];
            fn name(self) -> &'static str {
                match self {
                    $(Self::$variant => $name),+
                }
            }
        }
        impl ::core::str::FromStr for $ty {
            type Err = $crate::kinds::UnknownChoice;
            fn from_str(s: &str) -> Result<Self, Self::Err> {
                match s {
                    $($name => Ok(Self::$variant),)+
                    _ => Err($crate::kinds::UnknownChoice {
                        value: s.into(),
                        choices: <Self as $crate::kinds::Choice>::NAMES,
                    }),
                }
            }
        }
        impl ::core::fmt::Display for $ty {
            fn fmt(&self, f: &mut ::core::fmt::Formatter<'_>) -> ::core::fmt::Result {
                f.write_str($crate::kinds::Choice::name(*self))
            }
        }
    };
}
