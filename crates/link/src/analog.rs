//! The analog front end: the board's sensor (displacement, µm) and drive (amplifier input,
//! V) behind one seam, [`FrontEnd`], and the converters' codes and scales.
//!
//! The control code works in µm and V; a front end turns them into converter codes and
//! back. Three implement it: the STM32F4's ADC and DAC (the firmware's board layer), the
//! on-chip simulated actuator ([`SimulatedActuator`], QEMU's stand-in and the self-test)
//! and the host over the serial link (the board's control mode, where the host applies the
//! commands and sends the measurements; [`super::device::Device`] is that front end).
//!
//! ## Converters and wiring (the design the constants describe)
//! | signal | converter | pin | code → value |
//! |---|---|---|---|
//! | drive (amplifier input) | 12-bit DAC, 0–3.3 V, into a level shifter ×(20/3.3) − 10 V | PA4 (DAC1 OUT1) | `u = (code − 2048) · 20/4096` V: code 0 = −10 V, 2048 = 0 V, 4095 = +9.995 V |
//! | sensor (displacement) | 12-bit ADC1, channel 1, 0–3.3 V, from a sensor amplifier with 0 µm at mid-scale | PA1 (ADC123_IN1) | `y = (code − 2048) · 100/4096` µm: ±50 µm |
//!
//! A code is a newtype ([`DacCode`], [`AdcCode`]) so a volt never goes to a register
//! unconverted; [`DriveScale::code`] saturates at the converter's range and says so.

/// A 12-bit DAC code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DacCode(pub u16);

/// A 12-bit ADC code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AdcCode(pub u16);

/// Largest 12-bit code.
pub const CODE_MAX: u16 = 4095;

/// The drive's scale: volts at the amplifier's input per DAC code.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DriveScale {
    /// Volts per least significant bit.
    pub volt_per_lsb: f32,
    /// The code of 0 V.
    pub zero_code: u16,
}

/// The driver board's drive: ±10 V over 12 bits.
pub const DRIVE: DriveScale = DriveScale { volt_per_lsb: 20.0 / 4096.0, zero_code: 2048 };

impl DriveScale {
    /// The code nearest to `v` volts, clamped to `0..=4095`, and whether it was clamped
    /// (a non-finite `v` gives the code of 0 V, clamped).
    pub fn code(&self, v: f32) -> (DacCode, bool) {
        if !v.is_finite() {
            return (DacCode(self.zero_code), true);
        }
        let x = v / self.volt_per_lsb + self.zero_code as f32;
        let r = if x >= 0.0 { x + 0.5 } else { x - 0.5 };
        if r < 0.0 {
            (DacCode(0), true)
        } else if r >= CODE_MAX as f32 + 1.0 {
            (DacCode(CODE_MAX), true)
        } else {
            (DacCode(r as u16), false)
        }
    }

    /// The volts of `code`.
    pub fn volts(&self, code: DacCode) -> f32 {
        (code.0.min(CODE_MAX) as f32 - self.zero_code as f32) * self.volt_per_lsb
    }
}

/// The sensor's scale: µm per ADC code.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorScale {
    /// Micrometres per least significant bit.
    pub um_per_lsb: f32,
    /// The code of 0 µm.
    pub zero_code: u16,
}

/// The driver board's sensor: ±50 µm over 12 bits.
pub const SENSOR: SensorScale = SensorScale { um_per_lsb: 100.0 / 4096.0, zero_code: 2048 };

impl SensorScale {
    /// The displacement of `code`, µm; `None` for a code at either end of the range (the
    /// sensor is saturated, its reading is not the displacement).
    pub fn um(&self, code: AdcCode) -> Option<f32> {
        if code.0 == 0 || code.0 >= CODE_MAX {
            return None;
        }
        Some((code.0 as f32 - self.zero_code as f32) * self.um_per_lsb)
    }
}

/// The seam between the control step and the actuator.
pub trait FrontEnd {
    /// The sensor: the displacement answering the last drive, `y[k-1]` (µm), or `None` if
    /// there is none (no drive yet, a saturated sensor, a conversion not done).
    fn sense(&mut self) -> Option<f32>;
    /// Drives `u` volts (already within the board's limits); returns what the actuator
    /// gets, after the converter's range and resolution.
    fn drive(&mut self, u: f32) -> f32;
}

/// The on-chip simulated actuator: the board's plant model ([`crate::plant::OnChipPlant`])
/// behind the seam, with ideal converters (no quantisation), so that the host computes the
/// same outputs bit for bit.
#[derive(Clone, Debug)]
pub struct SimulatedActuator {
    plant: crate::plant::OnChipPlant,
    y: Option<f32>,
}

impl SimulatedActuator {
    /// The actuator at rest.
    pub fn new(plant: crate::plant::OnChipPlant) -> Self {
        Self { plant, y: None }
    }
}

impl FrontEnd for SimulatedActuator {
    fn sense(&mut self) -> Option<f32> {
        self.y
    }

    fn drive(&mut self, u: f32) -> f32 {
        self.y = Some(self.plant.step(u));
        u
    }
}

/// A front end that has nothing attached (a board without converters): never a
/// measurement, every drive ignored.
#[derive(Clone, Copy, Debug, Default)]
pub struct NoFrontEnd;

impl FrontEnd for NoFrontEnd {
    fn sense(&mut self) -> Option<f32> {
        None
    }
    fn drive(&mut self, _u: f32) -> f32 {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drive_codes_round_and_saturate_at_the_converter() {
        assert_eq!(DRIVE.code(0.0), (DacCode(2048), false));
        assert_eq!(DRIVE.code(-10.0), (DacCode(0), false));
        assert_eq!(DRIVE.code(10.0), (DacCode(4095), true));
        assert_eq!(DRIVE.code(-10.1), (DacCode(0), true));
        assert_eq!(DRIVE.code(150.0), (DacCode(4095), true));
        assert_eq!(DRIVE.code(f32::NAN), (DacCode(2048), true));
        assert_eq!(DRIVE.code(f32::INFINITY), (DacCode(2048), true));
        // Round trip within half a step over the range.
        for i in -1000..1000 {
            let v = i as f32 * 0.00999;
            let (c, sat) = DRIVE.code(v);
            assert!(!sat);
            assert!((DRIVE.volts(c) - v).abs() <= DRIVE.volt_per_lsb / 2.0 + 1e-6, "{v}");
        }
    }

    #[test]
    fn sensor_codes_scale_and_the_range_ends_are_not_readings() {
        assert_eq!(SENSOR.um(AdcCode(2048)), Some(0.0));
        assert_eq!(SENSOR.um(AdcCode(2048 + 41)), Some(41.0 * 100.0 / 4096.0));
        assert_eq!(SENSOR.um(AdcCode(0)), None);
        assert_eq!(SENSOR.um(AdcCode(4095)), None);
        assert_eq!(SENSOR.um(AdcCode(u16::MAX)), None);
    }
}
