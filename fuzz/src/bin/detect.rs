//! Fuzz target: lensblur::fuzz::Target::Detect.
fn main() {
    afl::fuzz!(|data: &[u8]| {
        let _ = lensblur::fuzz::Target::Detect.run(data);
    });
}
