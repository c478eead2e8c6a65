//! [`code_table!`]: a protocol's table of one-byte codes, written once.
//!
//! Each entry `Variant = code` becomes an enum variant and both directions of the mapping, so a
//! code cannot be added to the decoder and forgotten in the encoder (or the reverse), and a code
//! written twice is a compile error (duplicate discriminant or unreachable pattern).
//!
//! * Closed table (the protocol defines every code the decoder accepts): a `#[repr(u8)]` enum
//!   with the codes as discriminants, `from_code(u8) -> Option<Self>`, `code()`,
//!   `TryFrom<u8>` (the error is the code) and `From<Self> for u8`.
//! * Open table (any other code must still be carried, e.g. a device's error number):
//!   the same entries plus a last `other Unknown(u8);` clause, giving a variant
//!   `Unknown(u8)`, `From<u8>` (never fails), `code()` and `From<Self> for u8`. `From<u8>`
//!   never makes `Unknown` of a code the table names.
//!
//! The idea is smoltcp's `enum_with_unknown!`; this is written for this crate.

/// Declares an enum of one-byte protocol codes and both directions of its mapping once (see the
/// [module](crate::code_table) docs for what each form generates).
///
/// ```text
/// code_table! {
///     /// Instruction codes.
///     #[derive(Debug, Clone, Copy, PartialEq, Eq)]
///     pub enum Instruction {
///         /// 0x01.
///         Ping = 0x01,
///     }
/// }
/// code_table! {
///     /// Fault codes.
///     #[derive(Debug, Clone, Copy, PartialEq, Eq)]
///     pub enum Fault {
///         /// 1.
///         OverVoltage = 1,
///     }
///     /// Any other code.
///     other Unknown(u8);
/// }
/// ```
macro_rules! code_table {
    (
        $(#[$attr:meta])*
        $vis:vis enum $name:ident {
            $( $(#[$vattr:meta])* $variant:ident = $code:literal ),+ $(,)?
        }
        $(#[$uattr:meta])*
        other Unknown(u8);
    ) => {
        $(#[$attr])*
        $vis enum $name {
            $( $(#[$vattr])* $variant, )+
            $(#[$uattr])*
            Unknown(u8),
        }

        impl $name {
            /// The code byte.
            pub const fn code(self) -> u8 {
                match self {
                    $( Self::$variant => $code, )+
                    Self::Unknown(code) => code,
                }
            }
        }

        impl From<u8> for $name {
            fn from(code: u8) -> Self {
                match code {
                    $( $code => Self::$variant, )+
                    other => Self::Unknown(other),
                }
            }
        }

        impl From<$name> for u8 {
            fn from(value: $name) -> u8 {
                value.code()
            }
        }
    };
    (
        $(#[$attr:meta])*
        $vis:vis enum $name:ident {
            $( $(#[$vattr:meta])* $variant:ident = $code:literal ),+ $(,)?
        }
    ) => {
        $(#[$attr])*
        #[repr(u8)]
        $vis enum $name {
            $( $(#[$vattr])* $variant = $code, )+
        }

        impl $name {
            /// The entry for a code byte, if the table has one.
            pub const fn from_code(code: u8) -> Option<Self> {
                match code {
                    $( $code => Some(Self::$variant), )+
                    _ => None,
                }
            }

            /// The code byte.
            pub const fn code(self) -> u8 {
                self as u8
            }
        }

        impl TryFrom<u8> for $name {
            /// The code the table does not have.
            type Error = u8;

            fn try_from(code: u8) -> Result<Self, u8> {
                Self::from_code(code).ok_or(code)
            }
        }

        impl From<$name> for u8 {
            fn from(value: $name) -> u8 {
                value.code()
            }
        }
    };
}

pub(crate) use code_table;

#[cfg(test)]
mod tests {
    code_table! {
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        enum Closed {
            A = 0x01,
            B = 0x80,
        }
    }

    code_table! {
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        enum Open {
            A = 1,
            B = 7,
        }
        other Unknown(u8);
    }

    #[test]
    fn closed_table_round_trips_and_refuses_other_codes() {
        for code in 0..=u8::MAX {
            match Closed::from_code(code) {
                Some(v) => {
                    assert_eq!(v.code(), code);
                    assert_eq!(u8::from(v), code);
                    assert_eq!(Closed::try_from(code), Ok(v));
                }
                None => {
                    assert!(code != 0x01 && code != 0x80, "{code:#x} is in the table");
                    assert_eq!(Closed::try_from(code), Err(code));
                }
            }
        }
        assert_eq!(Closed::B as u8, 0x80);
    }

    #[test]
    fn open_table_keeps_every_code() {
        for code in 0..=u8::MAX {
            let v = Open::from(code);
            assert_eq!(u8::from(v), code);
            assert_eq!(matches!(v, Open::Unknown(_)), code != 1 && code != 7);
        }
        assert_eq!(Open::from(7), Open::B);
    }
}
