//! flexloop-observer: the observer process of the loop (see `flexloop_node::observer`).

fn main() {
    std::process::exit(flexloop_node::main_for(flexloop_node::Role::Observer));
}
