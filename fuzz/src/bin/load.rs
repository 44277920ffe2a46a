//! Fuzz target: lensblur::fuzz::Target::Load.
fn main() {
    afl::fuzz!(|data: &[u8]| {
        let _ = lensblur::fuzz::Target::Load.run(data);
    });
}
