struct Celsius(f32);

#[pipes_core::function(outputs = "ok")]
fn set_temperature(t: Celsius) -> bool {
    t.0 > 0.0
}

fn main() {}
