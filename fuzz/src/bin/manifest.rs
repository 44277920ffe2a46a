//! Fuzz target: lensblur::fuzz::Target::Manifest.
fn main() {
    afl::fuzz!(|data: &[u8]| {
        let _ = lensblur::fuzz::Target::Manifest.run(data);
    });
}
