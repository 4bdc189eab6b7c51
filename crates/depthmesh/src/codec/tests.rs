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

#[test]
fn random_images_of_odd_sizes_round_trip() {
    let mut rng = rand::rngs::SmallRng::seed_from_u64(2);
    for (width, height) in [(2, 3), (5, 1), (65, 63), (129, 130), (640, 65)] {
        // A smooth surface with holes and the occasional far jump, like a depth frame.
        round_trip(&image(width, height, |x, y| match rng.gen_range(0..20) {
            0 => 0,
            1 => u16::MAX,
            2 => rng.gen(),
            _ => (1000 + 3 * x + 5 * y + rng.gen_range(0..4)) as u16,
        }));
    }
}

/// A varied image whose streams are long enough to cut anywhere.
fn varied() -> RawDepth {
    image(37, 29, |x, y| {
        if (x * y) % 7 == 0 {
            0
        } else {
            (900 + x * 31 + y * 17 + (x * x) % 13) as u16
        }
    })
}

#[test]
fn truncated_streams_are_errors() {
    let depth = varied();
    let mut bytes = Vec::new();
    for codec in Codec::ALL {
        codec.encode(&depth, &mut bytes);
        for cut in 0..bytes.len() {
            let result = codec.decode(&bytes[..cut], 10_000);
            assert!(
                matches!(result, Err(Error::Codec { .. })),
                "{codec} cut at {cut} of {}",
                bytes.len()
            );
        }
    }
}

#[test]
fn corrupt_streams_never_panic_and_trailing_bytes_are_errors() {
    let depth = varied();
    let mut rng = rand::rngs::SmallRng::seed_from_u64(3);
    let mut bytes = Vec::new();
    for codec in Codec::ALL {
        codec.encode(&depth, &mut bytes);
        for _ in 0..300 {
            let mut bad = bytes.clone();
            for _ in 0..rng.gen_range(1..4) {
                let i = rng.gen_range(0..bad.len());
                bad[i] ^= 1 << rng.gen_range(0..8);
            }
            // Lossless payloads cannot all detect a changed value, but
            // none may panic or decode more than the limit.
            if let Ok(decoded) = codec.decode(&bad, 10_000) {
                assert!(decoded.data().len() <= 10_000);
            }
        }
        bytes.extend_from_slice(&[0; 4]);
        assert!(
            codec.decode(&bytes, 10_000).is_err(),
            "{codec} with 4 more bytes"
        );
    }
}

#[test]
fn streams_over_the_pixel_limit_or_of_another_codec_are_refused() {
    let depth = varied();
    let mut bytes = Vec::new();
    for codec in Codec::ALL {
        codec.encode(&depth, &mut bytes);
        let e = codec.decode(&bytes, 37 * 29 - 1).unwrap_err().to_string();
        assert!(e.contains("over the limit of 1072 pixels"), "{e}");
        // A claimed 100000×100000 image is refused before anything is allocated.
        let size_at = if codec == Codec::Rvl { 12 } else { 4 };
        bytes[size_at..size_at + 8].copy_from_slice(&[0xa0, 0x86, 0x01, 0, 0xa0, 0x86, 0x01, 0]);
        let e = codec
            .decode(&bytes, u64::from(u32::MAX))
            .unwrap_err()
            .to_string();
        assert!(e.contains("100000×100000 is over the limit"), "{e}");
        for other in Codec::ALL.into_iter().filter(|&c| c != codec) {
            other.encode(&depth, &mut bytes);
            assert!(
                codec.decode(&bytes, 10_000).is_err(),
                "{codec} read {other}"
            );
        }
    }
}

#[test]
fn scales_travel_with_the_image() {
    let mut depth = varied();
    depth = RawDepth::new(depth.width(), depth.height(), 5000.0, depth.into_data()).unwrap();
    round_trip(&depth);
}

/// The pattern of `testdata/pypi_rvl_64x48.bin` (see `testdata/README.md`).
fn pypi_pattern() -> RawDepth {
    image(64, 48, |x, y| {
        if (7 * x + 3 * y) % 11 == 0 {
            0
        } else {
            (800 + 13 * x + 29 * y + (x * y) % 17) as u16
        }
    })
}

#[test]
fn rvl_reads_an_independent_encoders_stream_bare_and_ros_framed() {
    let file = include_bytes!("testdata/pypi_rvl_64x48.bin");
    let (count, payload) = file.split_at(4);
    assert_eq!(count, 3072u32.to_le_bytes());
    let expected = pypi_pattern();

    let mut values = vec![0; 3072];
    rvl::decode_payload(payload, &mut values).unwrap();
    assert_eq!(values, expected.data());
    let mut ours = Vec::new();
    rvl::encode_payload(expected.data(), &mut ours);
    assert_eq!(ours, payload, "same bytes as the independent encoder");

    // ROS framing: ConfigHeader {INV_DEPTH, 0.0, 0.0}, cols, rows, payload.
    let mut ros = Vec::new();
    ros.extend_from_slice(&[0; 12]);
    ros.extend_from_slice(&64u32.to_le_bytes());
    ros.extend_from_slice(&48u32.to_le_bytes());
    ros.extend_from_slice(payload);
    let decoded = Codec::Rvl.decode(&ros, 3072).unwrap();
    assert_eq!(decoded, expected, "millimetres, as ROS means 16UC1");
    Codec::Rvl.encode(&expected, &mut ours);
    assert_eq!(
        ours, ros,
        "millimetre images are framed byte for byte as ROS frames them"
    );
}

#[test]
fn rvl_differences_wrap_as_the_signed_variant_writes_them() {
    // rvl.compress(np.array([0, 0, 5, 6, 7, 0, 65535, 1], np.uint16)) from
    // the PyPI package: 65535 after 7 is the difference -8, not +65528.
    let stream = [
        0x08, 0, 0, 0, 0x12, 0x22, 0xa1, 0x23, 0x00, 0x00, 0x40, 0xf1,
    ];
    let mut values = [1u16; 8];
    rvl::decode_payload(&stream[4..], &mut values).unwrap();
    assert_eq!(values, [0, 0, 5, 6, 7, 0, 65535, 1]);
}

#[test]
fn reused_encoders_and_decoders_carry_nothing_from_frame_to_frame() {
    let frames = [
        varied(),
        pypi_pattern(),
        image(5, 4, |x, y| (x * 1000 + y) as u16),
        varied(),
    ];
    for codec in Codec::ALL {
        let (mut encoder, mut decoder) = (Encoder::new(codec), Decoder::new(codec, 10_000));
        let (mut bytes, mut decoded) = (Vec::new(), RawDepth::default());
        for frame in &frames {
            encoder.encode(frame, &mut bytes);
            decoder.decode_into(&bytes, &mut decoded).unwrap();
            assert_eq!(&decoded, frame, "{codec}");
        }
    }
}
