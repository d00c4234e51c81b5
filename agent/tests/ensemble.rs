//! An agent with an ensemble acts on the mean of its nets' Q maps.

use agent::Agent;
use policy::{Mode, PolicyConfig};
use qnet::{Device, NetInput, QNetConfig};
use sim::{Camera, Primitive, SimConfig, Tabletop};

#[test]
fn an_ensemble_acts_on_the_mean_of_its_nets_q_maps() {
    let sim = SimConfig::with_pixel_size(0.004);
    let tabletop = Tabletop::new(&sim).unwrap();
    let obs = Camera::new(tabletop.grid()).render(&tabletop);
    let net = QNetConfig {
        trunk_widths: vec![4, 8],
        head_width: 16,
        ..QNetConfig::default()
    };
    let make = || {
        Agent::new(
            &net,
            &sim,
            PolicyConfig::default(),
            Mode::PushGrasp,
            &Device::flex(),
        )
    };
    // Fresh nets: each drawn with its own weights.
    let (one, other) = (make(), make());
    let mut pair = one.clone();
    pair.join_ensemble(other.nets()).unwrap();
    let input = NetInput::encode(&obs, 1);
    for primitive in [Primitive::Grasp, Primitive::Push] {
        let a = one.q_maps(primitive, &input).unwrap();
        let b = other.q_maps(primitive, &input).unwrap();
        assert_ne!(
            a.values(),
            b.values(),
            "{primitive:?}: two fresh nets agree"
        );
        let mean = pair.q_maps(primitive, &input).unwrap();
        assert_eq!(mean.values().len(), a.values().len());
        for ((m, x), y) in mean.values().iter().zip(a.values()).zip(b.values()) {
            assert!(
                (m - (x + y) / 2.0).abs() < 1e-5,
                "{primitive:?}: {m} for {x} and {y}"
            );
        }
    }
}
