//! One value per role, read and written by role (no array indexed by a
//! role cast to a number).

use flexloop_node::Role;

#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PerRole<T> {
    plant: T,
    observer: T,
    controller: T,
    logger: T,
}

impl<T> PerRole<T> {
    pub fn get(&self, role: Role) -> &T {
        match role {
            Role::Plant => &self.plant,
            Role::Observer => &self.observer,
            Role::Controller => &self.controller,
            Role::Logger => &self.logger,
        }
    }

    pub fn get_mut(&mut self, role: Role) -> &mut T {
        match role {
            Role::Plant => &mut self.plant,
            Role::Observer => &mut self.observer,
            Role::Controller => &mut self.controller,
            Role::Logger => &mut self.logger,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_role_has_its_own_value() {
        let mut counts = PerRole::<u32>::default();
        *counts.get_mut(Role::Observer) += 2;
        *counts.get_mut(Role::Controller) += 1;
        assert_eq!(
            Role::ALL.map(|r| *counts.get(r)),
            [0, 2, 1, 0],
            "plant, observer, controller, logger"
        );
    }
}
