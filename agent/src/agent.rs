//! [`Agent`]: nets, their rotation geometry, the policy settings and the mode, turning an
//! observation and a goal into a decision.

use actor::{Decision, Mode, PolicyConfig, PolicyInput, QMaps};
use qnet::{Geometry, NetInput, QNetConfig, QNetError, QNets};
use rand_chacha::ChaCha8Rng;
use sim::{Heightmaps, ObjectId, Primitive};

/// The nets acting through the policy.
#[derive(Clone)]
pub struct Agent {
    pub nets: QNets,
    pub geometry: Geometry,
    pub policy: PolicyConfig,
    pub mode: Mode,
}

/// A decision and the Q maps it was made on (push maps where the mode pushes).
pub struct Choice {
    pub decision: Decision,
    pub grasp: QMaps,
    pub push: Option<QMaps>,
}

/// Why an agent could not decide.
#[derive(Debug, thiserror::Error)]
pub enum AgentError {
    #[error(transparent)]
    Net(#[from] QNetError),
    #[error(transparent)]
    Policy(#[from] actor::ActorError),
}

impl Agent {
    /// Fresh nets of `net` for `side x side` heightmaps on the selected backend.
    pub fn new(net: &QNetConfig, side: usize, policy: PolicyConfig, mode: Mode) -> Self {
        let device = qnet::Backend::selected().device();
        Self {
            nets: QNets::new(net, &device),
            geometry: Geometry::new(side, net),
            policy,
            mode,
        }
    }

    /// Q maps for all rotations, then the hierarchical choice under exploration `epsilon`.
    pub fn decide(
        &self,
        obs: &Heightmaps,
        goal: ObjectId,
        pushes_so_far: usize,
        epsilon: f32,
        rng: &mut ChaCha8Rng,
    ) -> Result<Choice, AgentError> {
        let input = NetInput::encode(obs, goal);
        let grasp = self
            .nets
            .all_rotations(Primitive::Grasp, &input, &self.geometry)?;
        let push = match self.mode {
            Mode::PushGrasp => Some(self.nets.all_rotations(
                Primitive::Push,
                &input,
                &self.geometry,
            )?),
            Mode::GraspOnly => None,
        };
        let policy_input = PolicyInput {
            obs,
            goal,
            grasp: &grasp,
            push: push.as_ref(),
            pushes_so_far,
        };
        let decision = actor::choose(&self.policy, self.mode, &policy_input, epsilon, rng)?;
        Ok(Choice {
            decision,
            grasp,
            push,
        })
    }
}
