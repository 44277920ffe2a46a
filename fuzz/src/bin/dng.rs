//! Fuzz target: lensblur::fuzz::Target::Dng.
fn main() {
    afl::fuzz!(|data: &[u8]| {
        let _ = lensblur::fuzz::Target::Dng.run(data);
    });
}
