//! flexloop-logger: the logger process of the loop (see `flexloop_node::logger`).

fn main() {
    std::process::exit(flexloop_node::main_for(flexloop_node::Role::Logger));
}
