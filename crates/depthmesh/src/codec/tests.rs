//! Round trips of every codec and refusal of bad streams.

use super::*;
use rand::{Rng, SeedableRng};

fn image(width: u32, height: u32, mut f: impl FnMut(u32, u32) -> u16) -> RawDepth {
    let mut data = Vec::new();
    for y in 0..height {
        for x in 0..width {
            data.push(f(x, y));
        }
    }
    RawDepth::new(width, height, 1000.0, data).unwrap()
}

fn round_trip(depth: &RawDepth) {
    let mut bytes = Vec::new();
    for codec in Codec::ALL {
        codec.encode(depth, &mut bytes);
        let back = codec
            .decode(&bytes, u64::from(depth.width() * depth.height()))
            .unwrap_or_else(|e| panic!("{codec} {}×{}: {e}", depth.width(), depth.height()));
        assert_eq!(&back, depth, "{codec} {}×{}", depth.width(), depth.height());
    }
}

#[test]
fn every_codec_round_trips_edge_cases() {
    let mut rng = rand::rngs::SmallRng::seed_from_u64(1);
    round_trip(&image(64, 48, |_, _| 0));
    round_trip(&image(33, 17, |_, _| u16::MAX));
    round_trip(&image(1, 1, |_, _| 7));
    round_trip(&image(301, 1, |x, _| (x * 211) as u16));
    round_trip(&image(1, 203, |_, y| 65535 - y as u16));
    round_trip(&image(97, 131, |_, _| rng.gen()));
    round_trip(&image(97, 131, |x, y| {
        if (x + y) % 3 == 0 {
            0
        } else {
            60000 + (x * y % 5000) as u16
        }
    }));
}
