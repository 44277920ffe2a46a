//! Fuzz target: lensblur::fuzz::Target::Profile.
fn main() {
    afl::fuzz!(|data: &[u8]| {
        let _ = lensblur::fuzz::Target::Profile.run(data);
    });
}
