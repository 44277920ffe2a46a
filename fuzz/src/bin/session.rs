//! Fuzz target: lensblur::fuzz::Target::Session.
fn main() {
    afl::fuzz!(|data: &[u8]| {
        let _ = lensblur::fuzz::Target::Session.run(data);
    });
}
