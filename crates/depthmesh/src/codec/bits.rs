//! Bit streams, least significant bit first, for the default codec's raw
//! bits: the level table and the low bits of large residuals.

use crate::error::{Error, Result};

/// Appends bits to a byte vector.
#[derive(Debug, Default)]
pub(super) struct BitWriter {
    bytes: Vec<u8>,
    pending: u64,
    count: u32,
}

impl BitWriter {
    /// Empties the writer, keeping its allocation.
    pub fn clear(&mut self) {
        self.bytes.clear();
        self.pending = 0;
        self.count = 0;
    }

    /// Writes the low `bits` (at most 32) bits of `value`.
    #[inline]
    pub fn put(&mut self, value: u32, bits: u32) {
        debug_assert!(bits <= 32 && u64::from(value) < 1u64 << bits);
        self.pending |= u64::from(value) << self.count;
        self.count += bits;
        if self.count >= 32 {
            self.bytes
                .extend_from_slice(&(self.pending as u32).to_le_bytes());
            self.pending >>= 32;
            self.count -= 32;
        }
    }

    /// Writes `value` as an Elias gamma code of `value + 1`: the bit length
    /// less one in zeros, then a one, then the bits below the top one.
    pub fn put_gamma(&mut self, value: u32) {
        let v = u64::from(value) + 1;
        let low_bits = 63 - v.leading_zeros();
        self.put(0, low_bits);
        self.put(1, 1);
        // Two halves, so a 32-bit remainder never needs a 33-bit write.
        let low = v & ((1 << low_bits) - 1);
        self.put((low & 0xffff) as u32, low_bits.min(16));
        self.put((low >> 16) as u32, low_bits.saturating_sub(16));
    }

    /// The bytes written, the last one padded with zero bits.
    pub fn finish(&mut self) -> &[u8] {
        let tail = self.count.div_ceil(8) as usize;
        self.bytes
            .extend_from_slice(&self.pending.to_le_bytes()[..tail]);
        self.pending = 0;
        self.count = 0;
        &self.bytes
    }
}

/// Reads bits written by [`BitWriter`]; running out is an error naming `codec`.
pub(super) struct BitReader<'a> {
    bytes: &'a [u8],
    position: usize,
    pending: u64,
    count: u32,
    codec: &'static str,
}

impl<'a> BitReader<'a> {
    pub fn new(bytes: &'a [u8], codec: &'static str) -> Self {
        BitReader {
            bytes,
            position: 0,
            pending: 0,
            count: 0,
            codec,
        }
    }

    /// Reads `bits` (at most 32) bits.
    #[inline]
    pub fn get(&mut self, bits: u32) -> Result<u32> {
        while self.count < bits {
            let Some(&byte) = self.bytes.get(self.position) else {
                return Err(Error::codec(
                    self.codec,
                    "bit stream ends early (truncated)",
                ));
            };
            self.pending |= u64::from(byte) << self.count;
            self.position += 1;
            self.count += 8;
        }
        let value = (self.pending & ((1u64 << bits) - 1)) as u32;
        self.pending >>= bits;
        self.count -= bits;
        Ok(value)
    }

    /// Reads a value written by [`BitWriter::put_gamma`].
    pub fn get_gamma(&mut self) -> Result<u32> {
        let mut low_bits = 0;
        while self.get(1)? == 0 {
            low_bits += 1;
            if low_bits > 32 {
                return Err(Error::codec(
                    self.codec,
                    "gamma code over 32 bits (corrupt)",
                ));
            }
        }
        let low = u64::from(self.get(low_bits.min(16))?)
            | u64::from(self.get(low_bits.saturating_sub(16))?) << 16;
        let value = ((1u64 << low_bits) | low) - 1;
        u32::try_from(value)
            .map_err(|_| Error::codec(self.codec, "gamma code over 32 bits (corrupt)"))
    }

    /// Whether every byte was read (padding bits of the last one aside).
    pub fn at_end(&self) -> bool {
        self.position == self.bytes.len() && self.count < 8
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bits_and_gamma_codes_round_trip() {
        let mut writer = BitWriter::default();
        let gammas = [0, 1, 2, 7, 65535, u32::MAX - 1, u32::MAX];
        for (i, &g) in gammas.iter().enumerate() {
            writer.put(i as u32 & 7, 3);
            writer.put_gamma(g);
            writer.put(0xdead_beef, 32);
        }
        let bytes = writer.finish().to_vec();
        let mut reader = BitReader::new(&bytes, "test");
        for (i, &g) in gammas.iter().enumerate() {
            assert_eq!(reader.get(3).unwrap(), i as u32 & 7);
            assert_eq!(reader.get_gamma().unwrap(), g);
            assert_eq!(reader.get(32).unwrap(), 0xdead_beef);
        }
        assert!(reader.at_end());
        assert!(reader.get(8).is_err());
        let mut zeros = BitReader::new(&[0; 8], "test");
        assert!(zeros.get_gamma().is_err());
    }
}
