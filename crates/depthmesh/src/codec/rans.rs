//! Range asymmetric numeral systems (rANS, Duda 2013) with a 32-bit state
//! and byte-wise renormalisation, over small alphabets whose frequencies
//! are counted per frame and sent with it. Division by a symbol's frequency
//! is a multiplication by its precomputed reciprocal (Giesen's method), so
//! encoding costs about what decoding does.

use crate::error::{Error, Result};

/// Frequencies sum to `1 << PROB_BITS`.
pub(super) const PROB_BITS: u32 = 12;
const PROB_SCALE: u32 = 1 << PROB_BITS;
/// The state stays in `[STATE_LOW, STATE_LOW << 8)` between symbols.
const STATE_LOW: u32 = 1 << 23;

/// Frequencies of an alphabet of `N` symbols summing to `PROB_SCALE`, or all
/// zero for an alphabet never used.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Frequencies<const N: usize>(pub [u16; N]);

impl<const N: usize> Frequencies<N> {
    /// Scales `counts` to sum to `PROB_SCALE`, every counted symbol keeping
    /// at least 1. The rounding error goes to the most frequent symbol.
    pub fn normalise(counts: &[u32; N]) -> Self {
        let total: u64 = counts.iter().map(|&c| u64::from(c)).sum();
        let mut freq = [0u16; N];
        if total == 0 {
            return Frequencies(freq);
        }
        for (f, &c) in freq.iter_mut().zip(counts) {
            if c > 0 {
                *f = (u64::from(c) * u64::from(PROB_SCALE) / total).max(1) as u16;
            }
        }
        let sum: i32 = freq.iter().map(|&f| i32::from(f)).sum();
        let largest = (0..N).max_by_key(|&i| freq[i]).unwrap_or(0);
        // At most N symbols were raised to 1, so with N far below
        // PROB_SCALE the largest stays positive.
        freq[largest] = (i32::from(freq[largest]) + PROB_SCALE as i32 - sum) as u16;
        Frequencies(freq)
    }

    /// Writes the table: the number of symbols up to the last used one
    /// (one byte), then their frequencies (`u16`, little-endian).
    pub fn write(&self, out: &mut Vec<u8>) {
        let used = self.0.iter().rposition(|&f| f > 0).map_or(0, |i| i + 1);
        out.push(used as u8);
        for f in &self.0[..used] {
            out.extend_from_slice(&f.to_le_bytes());
        }
    }

    /// Reads a table written by [`Frequencies::write`] from the start of
    /// `bytes`, returning it and the bytes after it.
    pub fn read<'a>(bytes: &'a [u8], codec: &'static str) -> Result<(Self, &'a [u8])> {
        let corrupt = |message: String| Error::codec(codec, format!("frequency table: {message}"));
        let (&used, rest) = bytes
            .split_first()
            .ok_or_else(|| corrupt("missing (truncated)".into()))?;
        let used = usize::from(used);
        if used > N {
            return Err(corrupt(format!("{used} symbols in an alphabet of {N}")));
        }
        if rest.len() < used * 2 {
            return Err(corrupt("ends early (truncated)".into()));
        }
        let (table, rest) = rest.split_at(used * 2);
        let mut freq = [0u16; N];
        for (f, le) in freq.iter_mut().zip(table.chunks_exact(2)) {
            *f = u16::from_le_bytes([le[0], le[1]]);
        }
        let sum: u32 = freq.iter().map(|&f| u32::from(f)).sum();
        if used > 0 && sum != PROB_SCALE {
            return Err(corrupt(format!(
                "frequencies sum to {sum}, not {PROB_SCALE}"
            )));
        }
        Ok((Frequencies(freq), rest))
    }
}

/// What the encoder needs of one symbol.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct EncodeSymbol {
    /// States at or over this are renormalised first.
    limit: u32,
    reciprocal: u32,
    shift: u32,
    bias: u32,
    complement: u32,
}

/// The encoder's view of a [`Frequencies`] table.
pub(super) fn encode_table<const N: usize>(freq: &Frequencies<N>) -> [EncodeSymbol; N] {
    let mut symbols = [EncodeSymbol::default(); N];
    let mut start = 0u32;
    for (symbol, &f) in symbols.iter_mut().zip(&freq.0) {
        let f = u32::from(f);
        if f > 0 {
            // x / f == (x * reciprocal) >> (32 + shift) for every state x;
            // a frequency of 1 is handled through the bias instead.
            let (reciprocal, shift, bias) = if f < 2 {
                (u32::MAX, 0, start + PROB_SCALE - 1)
            } else {
                let shift = 32 - (f - 1).leading_zeros();
                let reciprocal = (1u64 << (shift + 31)).div_ceil(u64::from(f)) as u32;
                (reciprocal, shift - 1, start)
            };
            *symbol = EncodeSymbol {
                limit: ((STATE_LOW >> PROB_BITS) << 8) * f,
                reciprocal,
                shift,
                bias,
                complement: PROB_SCALE - f,
            };
        }
        start += f;
    }
    symbols
}

/// Encodes `symbols` with `table` into `out` (replacing its content), in
/// the order [`RansDecoder`] reads them. Symbols at even and odd positions
/// go through two states, so consecutive symbols do not wait on each
/// other's multiplications; both share one byte stream. rANS encodes last
/// to first, so the bytes are written reversed, then turned round.
pub(super) fn encode_all(symbols: &[u8], table: &[EncodeSymbol], out: &mut Vec<u8>) {
    out.clear();
    out.reserve(symbols.len() / 2 + 16);
    let (mut even, mut odd) = (STATE_LOW, STATE_LOW);
    let mut i = symbols.len();
    if i % 2 == 1 {
        i -= 1;
        even = put(even, &table[usize::from(symbols[i])], out);
    }
    while i > 0 {
        i -= 2;
        odd = put(odd, &table[usize::from(symbols[i + 1])], out);
        even = put(even, &table[usize::from(symbols[i])], out);
    }
    out.extend_from_slice(&odd.to_le_bytes());
    out.extend_from_slice(&even.to_le_bytes());
    out.reverse();
}

/// Encodes one symbol (which must have a frequency) onto state `x`,
/// pushing the bytes it renormalises out, and returns the new state.
#[inline(always)]
fn put(mut x: u32, symbol: &EncodeSymbol, reversed: &mut Vec<u8>) -> u32 {
    while x >= symbol.limit {
        reversed.push(x as u8);
        x >>= 8;
    }
    let q = ((u64::from(x) * u64::from(symbol.reciprocal)) >> 32) as u32 >> symbol.shift;
    x + symbol.bias + q * symbol.complement
}

/// The decoder's view of a [`Frequencies`] table: the symbol of every slot.
#[derive(Clone, Debug)]
pub(super) struct DecodeTable {
    slots: Vec<u8>,
    freq: Vec<u16>,
    start: Vec<u16>,
}

impl DecodeTable {
    /// The table of `freq`, which [`Frequencies::read`] has checked.
    pub fn new<const N: usize>(freq: &Frequencies<N>) -> Self {
        let mut table = DecodeTable {
            slots: Vec::with_capacity(PROB_SCALE as usize),
            freq: freq.0.to_vec(),
            start: Vec::with_capacity(N),
        };
        for (symbol, &f) in freq.0.iter().enumerate() {
            table.start.push(table.slots.len() as u16);
            table
                .slots
                .extend(std::iter::repeat_n(symbol as u8, usize::from(f)));
        }
        table
    }
}

/// Decodes what [`encode_all`] wrote, first symbol first.
pub(super) struct RansDecoder<'a> {
    states: [u32; 2],
    bytes: &'a [u8],
    position: usize,
    codec: &'static str,
}

impl<'a> RansDecoder<'a> {
    /// Starts decoding `bytes`; the states must be ones an encoder can end in.
    pub fn new(bytes: &'a [u8], codec: &'static str) -> Result<Self> {
        let Some(head) = bytes.get(..8) else {
            return Err(Error::codec(codec, "rANS stream shorter than its states"));
        };
        let states =
            [0, 4].map(|i| u32::from_be_bytes([head[i], head[i + 1], head[i + 2], head[i + 3]]));
        if !states
            .iter()
            .all(|s| (STATE_LOW..STATE_LOW << 8).contains(s))
        {
            return Err(Error::codec(codec, "rANS state out of range (corrupt)"));
        }
        Ok(RansDecoder {
            states,
            bytes,
            position: 8,
            codec,
        })
    }

    /// Decodes the symbol at position `i` with `table`; an empty table (a
    /// context the encoder never used) means the stream is corrupt.
    #[inline]
    pub fn get(&mut self, i: usize, table: &DecodeTable) -> Result<u8> {
        let state = self.states[i & 1];
        let slot = state & (PROB_SCALE - 1);
        let Some(&symbol) = table.slots.get(slot as usize) else {
            return Err(Error::codec(
                self.codec,
                "symbol in an unused context (corrupt)",
            ));
        };
        let s = usize::from(symbol);
        let mut x =
            u32::from(table.freq[s]) * (state >> PROB_BITS) + slot - u32::from(table.start[s]);
        while x < STATE_LOW {
            let Some(&byte) = self.bytes.get(self.position) else {
                return Err(Error::codec(
                    self.codec,
                    "rANS stream ends early (truncated)",
                ));
            };
            x = (x << 8) | u32::from(byte);
            self.position += 1;
        }
        self.states[i & 1] = x;
        Ok(symbol)
    }

    /// Checks the stream ended where the encoder started: the initial state,
    /// every byte read. Anything else means the stream was corrupt.
    pub fn finish(&self) -> Result<()> {
        if self.states != [STATE_LOW; 2] || self.position != self.bytes.len() {
            return Err(Error::codec(
                self.codec,
                "rANS stream does not end cleanly (corrupt)",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn symbols_round_trip_under_skewed_and_flat_frequencies() {
        let mut rng = rand::rngs::SmallRng::seed_from_u64(7);
        for skew in [1.0f64, 0.5, 0.05] {
            let symbols: Vec<u8> = (0..20_000)
                .map(|_| {
                    let mut s = 0u8;
                    while s < 20 && rng.gen::<f64>() > skew {
                        s += 1;
                    }
                    s
                })
                .collect();
            let mut counts = [0u32; 21];
            for &s in &symbols {
                counts[usize::from(s)] += 1;
            }
            let freq = Frequencies::normalise(&counts);
            assert_eq!(
                freq.0.iter().map(|&f| u32::from(f)).sum::<u32>(),
                PROB_SCALE
            );
            let mut table_bytes = Vec::new();
            freq.write(&mut table_bytes);
            let (read, rest) = Frequencies::<21>::read(&table_bytes, "test").unwrap();
            assert!(rest.is_empty() && read == freq);

            let mut bytes = Vec::new();
            encode_all(&symbols, &encode_table(&freq), &mut bytes);
            let table = DecodeTable::new(&freq);
            let mut decoder = RansDecoder::new(&bytes, "test").unwrap();
            for (i, &s) in symbols.iter().enumerate() {
                assert_eq!(decoder.get(i, &table).unwrap(), s);
            }
            decoder.finish().unwrap();
        }
    }

    #[test]
    fn bad_tables_are_refused() {
        for bytes in [&[][..], &[22][..], &[2, 0, 16][..], &[2, 0, 8, 1, 0][..]] {
            assert!(Frequencies::<21>::read(bytes, "test").is_err(), "{bytes:?}");
        }
    }
}
