//! Fuzz target: lensblur::fuzz::Target::Kernels.
fn main() {
    afl::fuzz!(|data: &[u8]| {
        let _ = lensblur::fuzz::Target::Kernels.run(data);
    });
}
