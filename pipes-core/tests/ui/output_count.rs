#[pipes_core::function(outputs = "time")]
fn get_comparator_reading() -> (u64, bool) {
    (0, true)
}

fn main() {}
