//! `fuzz_enum!` and `fuzz_struct!`: declare a type that derives `arbitrary::Arbitrary` and
//! gets the matching [`crate::enc::Enc`] (its inverse) from the same declaration, so the two
//! cannot drift apart. Enum variants are unit or struct-like; generics are not supported.

/// An enum deriving `Arbitrary`, with its `Enc`.
#[macro_export]
macro_rules! fuzz_enum {
    (
        $(#[$m:meta])*
        pub enum $name:ident {
            $(
                $(#[$vm:meta])*
                $var:ident $({ $($(#[$fm:meta])* $f:ident : $ft:ty),* $(,)? })?
            ),* $(,)?
        }
    ) => {
        $(#[$m])*
        #[derive(Debug, Clone, PartialEq, Eq, arbitrary::Arbitrary)]
        pub enum $name {
            $(
                $(#[$vm])*
                $var $({ $($(#[$fm])* $f : $ft),* })?
            ),*
        }

        impl $crate::enc::Enc for $name {
            #[allow(unused_variables)]
            fn enc(&self, out: &mut Vec<u8>) {
                const NAMES: &[&str] = &[$(stringify!($var)),*];
                let index = |n: &str| NAMES.iter().position(|x| *x == n).unwrap_or(0);
                match self {
                    $(
                        $name::$var $({ $($f),* })? => {
                            $crate::enc::variant(out, index(stringify!($var)), NAMES.len());
                            $($( $crate::enc::Enc::enc($f, out); )*)?
                        }
                    )*
                }
            }
        }
    };
}

/// A struct deriving `Arbitrary`, with its `Enc`.
#[macro_export]
macro_rules! fuzz_struct {
    (
        $(#[$m:meta])*
        pub struct $name:ident {
            $( $(#[$fm:meta])* pub $f:ident : $ft:ty ),* $(,)?
        }
    ) => {
        $(#[$m])*
        #[derive(Debug, Clone, PartialEq, Eq, arbitrary::Arbitrary)]
        pub struct $name {
            $( $(#[$fm])* pub $f : $ft ),*
        }

        impl $crate::enc::Enc for $name {
            fn enc(&self, out: &mut Vec<u8>) {
                $( $crate::enc::Enc::enc(&self.$f, out); )*
            }
        }
    };
}
