//! Fuzz target: lensblur::fuzz::Target::Exif.
fn main() {
    afl::fuzz!(|data: &[u8]| {
        let _ = lensblur::fuzz::Target::Exif.run(data);
    });
}
