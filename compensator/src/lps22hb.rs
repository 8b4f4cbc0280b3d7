//! LPS22HB barometer (the B-L475E-IOT01A's, I2C2 address 5Dh): what to write and how to read.
//! Register map and conversions from the LPS22HB datasheet (ST DocID027083) §9: WHO_AM_I 0Fh
//! = B1h, CTRL_REG1 10h, STATUS 27h, PRESS_OUT_XL/L/H 28h–2Ah (hPa = raw / 4096), TEMP_OUT_L/H
//! 2Bh–2Ch (°C = raw / 100); the address auto-increments (CTRL_REG2.IF_ADD_INC = 1 by default).

/// 7-bit I2C address (SA0 high on the board).
pub const ADDRESS: u8 = 0x5D;
/// WHO_AM_I register.
pub const WHO_AM_I: u8 = 0x0F;
/// WHO_AM_I value.
pub const ID: u8 = 0xB1;
/// CTRL_REG1 register.
pub const CTRL_REG1: u8 = 0x10;
/// CTRL_REG1 value: ODR 1 Hz (001), block data update (the three pressure bytes belong to one
/// conversion).
pub const CTRL_REG1_VALUE: u8 = 0x12;
/// STATUS register (first of the data burst).
pub const STATUS: u8 = 0x27;
/// Bytes of the data burst: STATUS, PRESS_OUT_XL/L/H, TEMP_OUT_L/H.
pub const BURST: usize = 6;
/// Plausible range of the sensor, hPa (datasheet: 260–1260 hPa absolute range).
pub const RANGE_HPA: (f32, f32) = (260.0, 1260.0);

/// Pressure (hPa) from a data burst read at [`STATUS`]; `None` before the first conversion
/// (STATUS.P_DA never set and all data zero) or outside the sensor's range.
pub fn decode(burst: &[u8; BURST], ever_converted: bool) -> Option<f32> {
    if burst[0] & 0x01 == 0 && !ever_converted {
        return None;
    }
    let raw = i32::from_le_bytes([burst[1], burst[2], burst[3], 0]) << 8 >> 8;
    let hpa = raw as f32 / 4096.0;
    (RANGE_HPA.0..=RANGE_HPA.1).contains(&hpa).then_some(hpa)
}
