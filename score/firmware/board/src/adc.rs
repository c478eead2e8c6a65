//! The ADC as Score sees it on the RP2040: four 12-bit single-ended channels (GPIO 26-29), the
//! temperature sensor (channel 4), and two *software* differential pairs, since the RP2040 has
//! no differential input: pair `A` = channel 0 − channel 1, pair `B` = channel 2 − channel 3,
//! each read back to back (2 µs apart) and returned as an offset-binary code.

/// Largest code of the 12-bit converter.
pub const FULL_SCALE: u16 = 4095;
/// Reference voltage (the Pico's 3.3 V rail).
pub const VREF: f32 = 3.3;
/// Single-ended channels.
pub const CHANNELS: u8 = 4;
/// Software differential pairs.
pub const PAIRS: u8 = 2;
/// The temperature sensor's ADC channel.
pub const TEMPERATURE_CHANNEL: u8 = 4;

/// The single-ended channels (positive, negative) of pair `k`.
pub fn pair_channels(k: u8) -> Option<(u8, u8)> {
    (k < PAIRS).then_some((2 * k, 2 * k + 1))
}

/// Offset-binary code of `pos − neg`: mid-scale (2048) for no difference, clamped to the code
/// range. Score reads it as `code · VREF / 4095 − VREF / 2`, so a zero difference shows as
/// +0.4 mV (half a code: 4095 has no middle) and the range is ±1.65 V.
pub fn differential_code(pos: u16, neg: u16) -> u16 {
    let mid = (FULL_SCALE as i32 + 1) / 2;
    (mid + pos as i32 - neg as i32).clamp(0, FULL_SCALE as i32) as u16
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn differences_are_offset_and_clamped() {
        assert_eq!(differential_code(1000, 1000), 2048);
        assert_eq!(differential_code(1500, 1000), 2548);
        assert_eq!(differential_code(0, 4095), 0);
        assert_eq!(differential_code(4095, 0), 4095);
        assert_eq!(pair_channels(1), Some((2, 3)));
        assert_eq!(pair_channels(2), None);
    }
}
