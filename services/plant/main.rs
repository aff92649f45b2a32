//! flexloop-plant: the plant process of the loop (see `flexloop_node::plant`).

fn main() {
    std::process::exit(flexloop_node::main_for(flexloop_node::Role::Plant));
}
