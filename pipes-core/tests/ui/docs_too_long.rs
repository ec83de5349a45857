//! A doc comment longer than a PIPES function may publish (2048 bytes).

/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
/// All work and no play makes a long doc comment. All work and no play makes a long doc comment. 
#[pipes_core::function(outputs = "y")]
fn chatty(x: f32) -> f32 {
    x
}

fn main() {}
