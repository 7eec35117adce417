//! Named bit sets: the status bytes of a Robo Cylinder response ([`status`](crate::status)) and
//! the PIO signal words ([`pio`](crate::pio)) are the same kind of thing, one macro makes both.

/// A newtype over an integer whose bits have names from a vendor document.
///
/// `raw` types keep every bit `from_bits` is given (a response's bytes must round-trip, unnamed
/// bits included); `masked` types drop bits that carry no signal (a word read from pins).
macro_rules! bit_flags {
    (@from_bits raw $name:ident $repr:ty) => {
        /// From the bits on the wire (every bit kept, named or not).
        pub const fn from_bits(bits: $repr) -> $name {
            $name(bits)
        }
    };
    (@from_bits masked $name:ident $repr:ty) => {
        /// From a word, bit n = port n; bits outside [`MASK`](Self::MASK) are dropped.
        pub const fn from_bits(bits: $repr) -> $name {
            $name(bits & $name::MASK)
        }
    };
    (
        $(#[$meta:meta])*
        $name:ident($repr:ty, $mode:ident) {
            $( $(#[$fmeta:meta])* $bit:literal => $flag:ident, $method:ident, $label:literal; )*
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Copy, PartialEq, Eq, Default, Hash)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        pub struct $name($repr);

        impl $name {
            $( $(#[$fmeta])* pub const $flag: $name = $name(1 << $bit); )*

            /// No bit set.
            pub const NONE: $name = $name(0);

            /// The bits that have a name.
            pub const MASK: $repr = 0 $( | 1 << $bit )*;

            /// Each named bit with its name in the vendor document, bit 0 first.
            pub const NAMED: &'static [($name, &'static str)] = &[ $( ($name::$flag, $label), )* ];

            bit_flags!(@from_bits $mode $name $repr);

            /// The bits.
            pub const fn bits(self) -> $repr {
                self.0
            }

            /// Whether every bit of `other` is set.
            pub const fn contains(self, other: $name) -> bool {
                self.0 & other.0 == other.0
            }

            /// This value with the bits of `other` set or cleared.
            #[must_use]
            pub const fn with(self, other: $name, set: bool) -> $name {
                if set { $name(self.0 | other.0) } else { $name(self.0 & !other.0) }
            }

            $(
                $(#[$fmeta])*
                pub const fn $method(self) -> bool {
                    self.contains($name::$flag)
                }
            )*

            /// The names of the bits that are set, bit 0 first.
            pub fn set_names(self) -> impl Iterator<Item = &'static str> {
                $name::NAMED.iter().filter(move |(f, _)| self.contains(*f)).map(|(_, n)| *n)
            }
        }

        impl core::ops::BitOr for $name {
            type Output = $name;
            fn bitor(self, rhs: $name) -> $name {
                $name(self.0 | rhs.0)
            }
        }

        impl core::fmt::Debug for $name {
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                let width = 2 * core::mem::size_of::<$repr>();
                write!(f, "{}(0x{:0width$X}", stringify!($name), self.0)?;
                for name in self.set_names() {
                    write!(f, " {name}")?;
                }
                write!(f, ")")
            }
        }
    };
}

pub(crate) use bit_flags;
