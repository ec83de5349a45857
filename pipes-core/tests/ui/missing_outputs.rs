#[pipes_core::function]
fn level() -> u8 {
    3
}

fn main() {}
