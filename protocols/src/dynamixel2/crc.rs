//! CRC-16/UMTS (a.k.a. CRC-16/BUYPASS) as used by Dynamixel Protocol 2.0: polynomial 0x8005,
//! initial value 0, no reflection, no final XOR. Check value: CRC("123456789") = 0xFEE8.

const POLY: u16 = 0x8005;

/// MSB-first lookup table, built at compile time from the polynomial (`TABLE[1] == 0x8005`).
const TABLE: [u16; 256] = {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = (i as u16) << 8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ POLY
            } else {
                crc << 1
            };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
};

/// Continues a running CRC over `bytes`. Start from `0` for a new packet.
pub fn update(mut crc: u16, bytes: &[u8]) -> u16 {
    for &b in bytes {
        let i = ((crc >> 8) as u8 ^ b) as usize;
        crc = (crc << 8) ^ TABLE[i];
    }
    crc
}

/// CRC of `bytes` from a zero start.
pub fn crc16(bytes: &[u8]) -> u16 {
    update(0, bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bit-by-bit reference form from protocols.md §1.3, independent of the table.
    fn bitwise(bytes: &[u8]) -> u16 {
        let mut crc: u16 = 0;
        for &b in bytes {
            crc ^= (b as u16) << 8;
            for _ in 0..8 {
                crc = if crc & 0x8000 != 0 {
                    (crc << 1) ^ 0x8005
                } else {
                    crc << 1
                };
            }
        }
        crc
    }

    #[test]
    fn check_value() {
        assert_eq!(crc16(b"123456789"), 0xFEE8);
    }

    #[test]
    fn table_matches_published_ends() {
        assert_eq!(
            TABLE[..10],
            [0x0000, 0x8005, 0x800F, 0x000A, 0x801B, 0x001E, 0x0014, 0x8011, 0x8033, 0x0036]
        );
        assert_eq!(TABLE[254..], [0x8207, 0x0202]);
    }

    #[test]
    fn table_agrees_with_bitwise_form() {
        let data: std::vec::Vec<u8> = (0..=255u8).chain((0..=255u8).rev()).collect();
        for n in 0..data.len() {
            assert_eq!(crc16(&data[..n]), bitwise(&data[..n]));
        }
    }

    #[test]
    fn running_crc_equals_one_shot() {
        let data = b"FF FF FD 00 running";
        for split in 0..data.len() {
            assert_eq!(update(crc16(&data[..split]), &data[split..]), crc16(data));
        }
    }
}
