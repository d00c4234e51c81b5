//! [`Agent`]: nets, their rotation geometry, the policy settings and the mode, turning an
//! observation and a goal into a decision.

use policy::{Decision, Mode, PolicyConfig, PolicyInput, QMaps};
use qnet::{ActingNets, Device, Geometry, NetInput, QNetConfig, QNetError, QNets, RotatedQMaps};
use rand_chacha::ChaCha8Rng;
use sim::{Action, Heightmaps, ObjectId, Primitive, SimConfig};

/// The nets acting through the policy.
#[derive(Clone)]
pub struct Agent {
    nets: QNets,
    /// `nets` in the form that acts (on the CPU, their inference form), rebuilt whenever
    /// their weights change.
    acting: ActingNets,
    /// More nets whose Q maps are averaged with `nets`' at every decision (an ensemble, for
    /// evaluation); empty when an actor acts in training.
    ensemble: Vec<ActingNets>,
    pub geometry: Geometry,
    /// How far the simulator's pushes move the tool (metres): the policy's goal guard
    /// predicts with it.
    pub push_length: f32,
    pub policy: PolicyConfig,
    pub mode: Mode,
}

/// A decision and the Q maps it was made on (push maps where the mode pushes).
pub struct Choice {
    pub decision: Decision,
    pub grasp: QMaps,
    pub push: Option<QMaps>,
}

/// What one environment decides on: what it sees, its goal, the pushes of its episode so
/// far, and its own exploration.
pub struct Situation<'a> {
    pub obs: &'a Heightmaps,
    /// The scene on the policy's landing view grid, where it names one
    /// ([`PolicyInput::landing_view`]).
    pub landing_view: Option<&'a Heightmaps>,
    pub goal: ObjectId,
    pub pushes_so_far: usize,
    /// Grasps not to make again ([`PolicyInput::failed_grasps`]).
    pub failed_grasps: &'a [Action],
    /// Whether a grasp has picked nothing since the last push
    /// ([`PolicyInput::grasp_failed_since_push`]).
    pub grasp_failed_since_push: bool,
    pub epsilon: f32,
    pub rng: &'a mut ChaCha8Rng,
}

/// Why an agent could not decide.
#[derive(Debug, thiserror::Error)]
pub enum AgentError {
    #[error(transparent)]
    Net(#[from] QNetError),
    #[error(transparent)]
    Policy(#[from] policy::PolicyError),
}

impl Agent {
    /// Fresh nets of `net` for the heightmaps of `sim` (validated) on `device`.
    pub fn new(
        net: &QNetConfig,
        sim: &SimConfig,
        policy: PolicyConfig,
        mode: Mode,
        device: &Device,
    ) -> Self {
        let nets = QNets::new(net, device);
        Self {
            acting: ActingNets::new(&nets).expect("fresh nets have an inference form"),
            nets,
            ensemble: Vec::new(),
            geometry: Geometry::new(sim.grid().expect("a validated sim config").side(), net),
            push_length: sim.push_length,
            policy,
            mode,
        }
    }

    /// The nets this agent acts with.
    pub fn nets(&self) -> &QNets {
        &self.nets
    }

    /// Acts with the weights in `bytes` (made by [`QNets::to_bytes`] for nets of this
    /// agent's configuration) from now on.
    pub fn load_weights(&mut self, bytes: &[u8]) -> Result<(), QNetError> {
        self.act_with(self.nets.clone().load_bytes(bytes)?)
    }

    /// Acts with `nets` (in inference form, of this agent's configuration) from now on.
    pub fn act_with(&mut self, nets: QNets) -> Result<(), QNetError> {
        self.acting = ActingNets::new(&nets)?;
        self.nets = nets;
        Ok(())
    }

    /// Averages `nets`' Q maps into every decision from now on (an ensemble member).
    pub fn join_ensemble(&mut self, nets: &QNets) -> Result<(), QNetError> {
        self.ensemble.push(ActingNets::new(nets)?);
        Ok(())
    }

    /// Q maps for all rotations, then the hierarchical choice in `situation`, under its
    /// exploration.
    pub fn decide(&self, situation: Situation<'_>) -> Result<Choice, AgentError> {
        let mut choices = self.decide_each(vec![situation])?;
        Ok(choices.pop().expect("one situation, one choice"))
    }

    /// [`Agent::decide`] in each of `situations` (several environments at once): their Q
    /// maps as one batch, then each one's choice with its own exploration.
    pub fn decide_each(&self, situations: Vec<Situation<'_>>) -> Result<Vec<Choice>, AgentError> {
        let inputs: Vec<NetInput> = situations
            .iter()
            .map(|s| NetInput::encode(s.obs, s.goal))
            .collect();
        let inputs: Vec<&NetInput> = inputs.iter().collect();
        let maps: Vec<(QMaps, Option<QMaps>)> = match self.mode {
            Mode::PushGrasp => self
                .q_maps_of_each([Primitive::Grasp, Primitive::Push], &inputs)?
                .into_iter()
                .map(|[grasp, push]| (grasp, Some(push)))
                .collect(),
            Mode::GraspOnly => self
                .q_maps_of_each([Primitive::Grasp], &inputs)?
                .into_iter()
                .map(|[grasp]| (grasp, None))
                .collect(),
        };
        situations
            .into_iter()
            .zip(maps)
            .map(|(s, (grasp, push))| {
                let policy_input = PolicyInput {
                    obs: s.obs,
                    goal: s.goal,
                    grasp: &grasp,
                    push: push.as_ref(),
                    pushes_so_far: s.pushes_so_far,
                    push_length: self.push_length,
                    landing_view: s.landing_view,
                    failed_grasps: s.failed_grasps,
                    grasp_failed_since_push: s.grasp_failed_since_push,
                };
                let decision =
                    policy::choose(&self.policy, self.mode, &policy_input, s.epsilon, s.rng)?;
                Ok(Choice {
                    decision,
                    grasp,
                    push,
                })
            })
            .collect()
    }

    /// One primitive's Q maps for all rotations: `nets`' alone, or the mean over the ensemble.
    pub fn q_maps(&self, primitive: Primitive, input: &NetInput) -> Result<QMaps, AgentError> {
        let mut maps = self.q_maps_of_each([primitive], &[input])?;
        let [maps] = maps.pop().expect("one input, one set of maps");
        Ok(maps)
    }

    /// [`Agent::q_maps`] of each of `primitives` for each of `inputs`, each net rotating
    /// each input once for all of them.
    fn q_maps_of_each<const N: usize>(
        &self,
        primitives: [Primitive; N],
        inputs: &[&NetInput],
    ) -> Result<Vec<[QMaps; N]>, AgentError> {
        let mut maps = self
            .acting
            .all_rotations_of_each(primitives, inputs, &self.geometry)?;
        if self.ensemble.is_empty() {
            return Ok(maps);
        }
        for nets in &self.ensemble {
            let more = nets.all_rotations_of_each(primitives, inputs, &self.geometry)?;
            for (sum, more) in maps.iter_mut().flatten().zip(more.iter().flatten()) {
                let sum = sum.values_mut().iter_mut();
                sum.zip(more.values()).for_each(|(s, q)| *s += q);
            }
        }
        let members = (1 + self.ensemble.len()) as f32;
        for mean in maps.iter_mut().flatten() {
            mean.values_mut().iter_mut().for_each(|s| *s /= members);
        }
        Ok(maps)
    }
}
