#[pipes_core::function(outputs = "time, letter")]
fn reading() -> (u64, char) {
    (0, 'a')
}

fn main() {}
