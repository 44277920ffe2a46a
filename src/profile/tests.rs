//! The profile's own rules: hull membership and the encoding of its stored numbers.

use super::*;

#[test]
fn hull_membership() {
    let square = [
        [-1.0, -1.0],
        [1.0, -1.0],
        [1.0, 1.0],
        [-1.0, 1.0],
        [0.0, 0.0],
    ];
    assert!(point_in_hull(&square, [0.3, -0.9], 1e-3));
    assert!(point_in_hull(&square, [1.0005, 0.0], 1e-3));
    assert!(!point_in_hull(&square, [1.01, 0.0], 1e-3));
    // A zoom whose widest aperture shrinks: no (1, −1) corner.
    let staircase = [[-1.0, -1.0], [1.0, -0.5], [1.0, 1.0], [-1.0, 1.0]];
    assert!(!point_in_hull(&staircase, [1.0, -1.0], 1e-3));
    assert!(point_in_hull(&staircase, [0.0, -0.75], 1e-3));
    // One focal length: a segment; one setting: a point.
    let line = [[0.0, -1.0], [0.0, 0.2], [0.0, 1.0]];
    assert!(point_in_hull(&line, [0.0, 0.5], 1e-3));
    assert!(!point_in_hull(&line, [0.1, 0.5], 1e-3));
    assert!(point_in_hull(&[[0.0, 0.0]], [0.0, 0.0005], 1e-3));
    assert!(!point_in_hull(&[[0.0, 0.0]], [0.0, 0.1], 1e-3));
}

#[test]
fn base64_round_trips() {
    for n in 0..7 {
        let bytes: Vec<u8> = (0..n).map(|i| (i * 37 + 11) as u8).collect();
        assert_eq!(base64_decode(&base64_encode(&bytes)).unwrap(), bytes);
    }
    assert_eq!(base64_encode(b"Man"), "TWFu");
    assert_eq!(base64_encode(b"Ma"), "TWE=");
    let v = vec![1.5, -2.25e-5, 3.0e7];
    let back = decode_f32(&encode_f32(&v)).unwrap();
    for (a, b) in v.iter().zip(&back) {
        assert!((a - b).abs() <= 1e-7 * a.abs());
    }
}
