struct NoConstructor;

#[pipes_core::class]
impl NoConstructor {
    fn get(&self) {}
}

struct BadMember;

#[pipes_core::class]
impl BadMember {
    #[constructor]
    fn new() -> Self {
        BadMember
    }

    #[outputs = "a, b"]
    fn get(&self) -> u8 {
        1
    }
}

fn main() {}
