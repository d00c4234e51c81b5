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
    /// More nets whose Q maps are averaged with `nets`' at every decision (an ensemble, for
    /// evaluation); empty when an actor acts in training.
    pub ensemble: Vec<QNets>,
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
            ensemble: Vec::new(),
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
        let grasp = self.q_maps(Primitive::Grasp, &input)?;
        let push = match self.mode {
            Mode::PushGrasp => Some(self.q_maps(Primitive::Push, &input)?),
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

    /// One primitive's Q maps for all rotations: `nets`' alone, or the mean over the ensemble.
    pub fn q_maps(&self, primitive: Primitive, input: &NetInput) -> Result<QMaps, AgentError> {
        let maps = self.nets.all_rotations(primitive, input, &self.geometry)?;
        if self.ensemble.is_empty() {
            return Ok(maps);
        }
        let mut sum = maps.values().to_vec();
        for nets in &self.ensemble {
            let more = nets.all_rotations(primitive, input, &self.geometry)?;
            sum.iter_mut().zip(more.values()).for_each(|(s, q)| *s += q);
        }
        let members = (1 + self.ensemble.len()) as f32;
        sum.iter_mut().for_each(|s| *s /= members);
        Ok(QMaps::new(maps.rotations(), maps.side(), sum)?)
    }
}
