//! One table per coded enum: the variant, its code on the wire and its one-line meaning are
//! written once, side by side, and `code`, `from_code`, `meaning`, `Display` and `ALL` are
//! generated from it. Adding a code (a GCS error, a result code, a status LED state, a request
//! kind) is one line in one table.

/// Define a `#[non_exhaustive]` enum whose variants carry a stable wire code and a meaning.
///
/// ```text
/// code_enum! {
///     /// Doc of the enum.
///     pub enum Name: u8 {
///         /// Doc of the variant.
///         Variant = 1 => "what it means, one line",
///     }
/// }
/// ```
macro_rules! code_enum {
    (
        $(#[$meta:meta])*
        $vis:vis enum $name:ident : $repr:ty {
            $(
                $(#[$vmeta:meta])*
                $variant:ident = $code:literal => $meaning:literal,
            )+
        }
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        #[non_exhaustive]
        $vis enum $name {
            $(
                $(#[$vmeta])*
                $variant,
            )+
        }

        impl $name {
            /// Every variant, in the table's order.
            pub const ALL: &'static [$name] = &[$($name::$variant),+];

            /// The code on the wire.
            pub const fn code(self) -> $repr {
                match self {
                    $($name::$variant => $code,)+
                }
            }

            /// The variant with wire code `code`; `None` for a code no variant has.
            pub const fn from_code(code: $repr) -> Option<Self> {
                match code {
                    $($code => Some($name::$variant),)+
                    _ => None,
                }
            }

            /// What it means, one line for people (CLI output, logs, reports).
            pub const fn meaning(self) -> &'static str {
                match self {
                    $($name::$variant => $meaning,)+
                }
            }
        }

        impl core::fmt::Display for $name {
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                f.write_str(self.meaning())
            }
        }
    };
}
