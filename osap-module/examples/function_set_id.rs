//! Prints the module's function-set id (`osap_module::FUNCTION_SET_ID`) in
//! hex, for `scripts/function-set-check.sh` to compare with the value each
//! firmware image embeds.

fn main() {
    println!("{:#010x}", osap_module::FUNCTION_SET_ID);
}
