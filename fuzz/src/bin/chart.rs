//! Fuzz target: lensblur::fuzz::Target::Chart.
fn main() {
    afl::fuzz!(|data: &[u8]| {
        let _ = lensblur::fuzz::Target::Chart.run(data);
    });
}
