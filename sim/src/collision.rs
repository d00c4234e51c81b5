//! Which bodies touch which: the gripper touches the table and the objects but not itself.

use rapier3d::prelude::Group;

pub(crate) const TABLE_GROUP: Group = Group::GROUP_1;
pub(crate) const OBJECT_GROUP: Group = Group::GROUP_2;
pub(crate) const GRIPPER_GROUP: Group = Group::GROUP_3;
