//! flexloop-controller: the controller process of the loop (see `flexloop_node::controller`).

fn main() {
    std::process::exit(flexloop_node::main_for(flexloop_node::Role::Controller));
}
