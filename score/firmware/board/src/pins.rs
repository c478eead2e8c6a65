//! Which GPIO is used by what. The RP2040 has GPIO 0-29; Score uses 0-15 for PWM outputs
//! (output `n` = GPIO `n`), 26-29 for the ADC, and lets `gpio`/`defgpio` take any of 0-25 that
//! no PWM output holds.

use score_core::hal::HalError;

/// GPIO pins on the chip.
pub const PINS: usize = 30;
/// Pins offered to `gpio`/`defgpio` (`0..DIGITAL_PINS`; 26-29 are the ADC inputs).
pub const DIGITAL_PINS: u8 = 26;

/// What a pin is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PinUse {
    /// Nothing (reset state).
    #[default]
    Free,
    /// Driven by a PWM slice.
    Pwm,
    /// Digital input.
    Input,
    /// Digital output.
    Output,
    /// Analogue input (ADC 0-3 on GPIO 26-29).
    Adc,
}

/// Pin ownership.
#[derive(Debug, Clone)]
pub struct PinTable {
    uses: [PinUse; PINS],
}

impl Default for PinTable {
    fn default() -> Self {
        Self::new()
    }
}

impl PinTable {
    /// GPIO 26-29 reserved for the ADC, the rest free.
    pub const fn new() -> Self {
        let mut uses = [PinUse::Free; PINS];
        let mut p = 26;
        while p < PINS {
            uses[p] = PinUse::Adc;
            p += 1;
        }
        Self { uses }
    }

    /// What `pin` does now.
    pub fn get(&self, pin: u8) -> PinUse {
        self.uses.get(pin as usize).copied().unwrap_or(PinUse::Adc)
    }

    /// Claims every pin of `pins` for `what`, or none of them: a pin used for something else
    /// is [`HalError::Exhausted`]; a pin that does not exist or is the ADC's is
    /// [`HalError::NoSuchChannel`]. Re-claiming for the same use is fine (redefinitions),
    /// and so is switching a digital pin between input and output.
    pub fn claim(&mut self, pins: &[u8], what: PinUse) -> Result<(), HalError> {
        for &p in pins {
            match self.get(p) {
                PinUse::Adc => return Err(HalError::NoSuchChannel),
                PinUse::Free => {}
                u if u == what => {}
                PinUse::Input | PinUse::Output
                    if matches!(what, PinUse::Input | PinUse::Output) => {}
                _ => return Err(HalError::Exhausted),
            }
        }
        for &p in pins {
            self.uses[p as usize] = what;
        }
        Ok(())
    }

    /// Frees `pins` (ADC pins stay reserved).
    pub fn release(&mut self, pins: &[u8]) {
        for &p in pins {
            if let Some(u) = self.uses.get_mut(p as usize) {
                if *u != PinUse::Adc {
                    *u = PinUse::Free;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn claims_conflict_only_across_uses() {
        let mut t = PinTable::new();
        t.claim(&[2, 3], PinUse::Pwm).unwrap();
        assert_eq!(t.claim(&[3], PinUse::Input), Err(HalError::Exhausted));
        assert_eq!(t.claim(&[4, 2], PinUse::Output), Err(HalError::Exhausted));
        assert_eq!(t.get(4), PinUse::Free, "all or nothing");
        t.claim(&[4], PinUse::Input).unwrap();
        t.claim(&[4], PinUse::Output).unwrap();
        assert_eq!(t.claim(&[27], PinUse::Input), Err(HalError::NoSuchChannel));
        t.release(&[2, 3, 27]);
        assert_eq!((t.get(2), t.get(27)), (PinUse::Free, PinUse::Adc));
    }
}
