//! Value parsers shared by the subcommands' flags: clap's own integer parsers answer `-1` with "invalid
//! digit found in string"; these say what the value must be.

use std::str::FromStr;

/// A whole number of type `T` (a count, an index or a seed: `T` is unsigned), or an error that says why
/// `s` is not one: negative, fractional, not a number, or too large.
pub fn whole<T>(s: &str) -> Result<T, String>
where
    T: FromStr + Bounded,
{
    let t = s.trim();
    if let Ok(v) = t.parse::<T>() {
        return Ok(v);
    }
    let rule = format!("must be a whole number from 0 to {}", T::MAX_TEXT);
    Err(match t.parse::<f64>() {
        Ok(x) if x.is_nan() => format!("not a number; it {rule}"),
        Ok(x) if x < 0.0 => format!("{t} is negative; the value {rule}"),
        Ok(x) if x.is_finite() && x.fract() != 0.0 => format!("{t} is not whole; the value {rule}"),
        Ok(_) => format!("{t} is too large; the value {rule}"),
        Err(_) => format!("'{t}' is not a number; the value {rule}"),
    })
}

/// The largest value of an unsigned integer type, as text (for [`whole`]'s messages).
pub trait Bounded {
    const MAX_TEXT: &'static str;
}

macro_rules! bounded {
    ($($t:ty => $max:literal),*) => {
        $(impl Bounded for $t {
            const MAX_TEXT: &'static str = $max;
        })*
    };
}

bounded!(u16 => "65535", u32 => "4294967295", u64 => "18446744073709551615",
         usize => "18446744073709551615");

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_of_bad_count_is_named() {
        assert_eq!(whole::<u32>("7"), Ok(7));
        assert_eq!(whole::<u64>(" 0 "), Ok(0));
        let err = |s: &str| whole::<u32>(s).unwrap_err();
        assert!(err("-1").starts_with("-1 is negative"), "{}", err("-1"));
        assert!(err("2.5").starts_with("2.5 is not whole"), "{}", err("2.5"));
        assert!(err("1e12").contains("too large"), "{}", err("1e12"));
        assert!(err("4294967296").contains("too large"));
        assert!(err("ten").contains("'ten' is not a number"));
        assert!(err("nan").starts_with("not a number"));
        assert!(err("-1").ends_with("from 0 to 4294967295"));
        // The stated maximum is the type's own.
        assert_eq!(u16::MAX.to_string(), u16::MAX_TEXT);
        assert_eq!(u32::MAX.to_string(), u32::MAX_TEXT);
        assert_eq!(u64::MAX.to_string(), u64::MAX_TEXT);
        assert_eq!(usize::MAX.to_string(), usize::MAX_TEXT);
    }
}
