//! [`SchemaError`]: why a payload read from shared memory was rejected by its `validate()`.
//!
//! Small and `Copy` (no `String`), so a real-time consumer can return, count and log it
//! without allocating. `field` names the offending field as written in the struct.

/// Why a shared-memory payload failed validation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SchemaError {
    /// A floating-point field held NaN or ±Inf.
    #[error("field `{field}` is not finite")]
    NonFinite {
        /// The field.
        field: &'static str,
    },
    /// A count exceeded the fixed capacity of its array.
    #[error("field `{field}` = {count} exceeds the capacity {capacity}")]
    CountOverCapacity {
        /// The count field.
        field: &'static str,
        /// The value found.
        count: u32,
        /// The capacity of the array it counts.
        capacity: u32,
    },
    /// A byte stored for an enum (or a 0/1 flag) had no valid meaning.
    #[error("field `{field}` holds the invalid discriminant {value}")]
    BadEnum {
        /// The field.
        field: &'static str,
        /// The raw value found.
        value: u32,
    },
    /// A finite number outside its documented range (e.g. a negative size).
    #[error("field `{field}` is out of range")]
    OutOfRange {
        /// The field.
        field: &'static str,
    },
    /// The payload's own format version differs from the one this build understands.
    #[error("format version {found} is not the supported version {expected}")]
    VersionMismatch {
        /// The version this build reads.
        expected: u32,
        /// The version found in the payload.
        found: u32,
    },
    /// The stored checksum does not match the payload's contents.
    #[error("checksum mismatch (stored {stored:#018x}, computed {computed:#018x})")]
    ChecksumMismatch {
        /// The checksum stored in the payload.
        stored: u64,
        /// The checksum computed over the payload.
        computed: u64,
    },
    /// Structural fields contradict each other (e.g. a weight count that does not match
    /// the layer sizes, or a used slot left unset).
    #[error("layout invalid: field `{field}`")]
    LayoutInvalid {
        /// The field.
        field: &'static str,
    },
}

/// Checks every element of `values` is finite.
pub(crate) fn finite_f32(field: &'static str, values: &[f32]) -> Result<(), SchemaError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(SchemaError::NonFinite { field })
    }
}

/// Checks every element of `values` is finite.
pub(crate) fn finite_f64(field: &'static str, values: &[f64]) -> Result<(), SchemaError> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(SchemaError::NonFinite { field })
    }
}

/// Checks a 0/1 flag byte.
pub(crate) fn flag(field: &'static str, value: u8) -> Result<(), SchemaError> {
    if value <= 1 {
        Ok(())
    } else {
        Err(SchemaError::BadEnum {
            field,
            value: u32::from(value),
        })
    }
}

/// Checks a count against a capacity.
pub(crate) fn count_within(
    field: &'static str,
    count: u32,
    capacity: usize,
) -> Result<(), SchemaError> {
    if (count as usize) <= capacity {
        Ok(())
    } else {
        Err(SchemaError::CountOverCapacity {
            field,
            count,
            capacity: u32::try_from(capacity).unwrap_or(u32::MAX),
        })
    }
}

/// Converts a bool to the 0/1 byte stored in shared memory (a `bool` there would make any
/// other byte value undefined behaviour on read).
pub const fn flag_byte(value: bool) -> u8 {
    value as u8
}
