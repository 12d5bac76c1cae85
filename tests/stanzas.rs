//! A cell that grows by stanzas: a second welding station `welding2` and a
//! second transport station `transport2`, each added to the topology by
//! one `[[station]]` stanza and given recipes in a directory of its own
//! (`recipes/welding2/`, `recipes/transport2/`): their kind comes from the
//! topology, the operator delivers their recipes, and an order that uses
//! both welding stations and both conveyors runs to done.

use crate::support::copy_dir;
use crate::support::rig::rig_grown;
use falc_model::records::OrderState;
use std::time::Duration;

const MORE: &str = r#"
[[station]]
name = "welding2"
kind = "welding"
commander = "cell"
[[station]]
name = "transport2"
kind = "transport"
commander = "cell"
"#;

/// Both robots weld at once, after both conveyors stored a carrier.
const TWEELING: &str = "\
tweeling.rcp: both welding stations at once (a cell grown by two stanzas).

-1  | start transport store        |       | gestart    | 2
-1  | start transport store        |       | tijdlimiet | 9
-2  | wait transport 60            |       | klaar      | 3
-2  | wait transport 60            |       | tijdlimiet | 9
-3  | start transport2 store       |       | gestart    | 4
-3  | start transport2 store       |       | tijdlimiet | 9
-4  | wait transport2 60           |       | klaar      | 5
-4  | wait transport2 60           |       | tijdlimiet | 9
-5  | start welding droog_dik 180  |       | gestart    | 6
-5  | start welding droog_dik 180  |       | tijdlimiet | 9
-6  | start welding2 droog_dun 180 |       | gestart    | 7
-6  | start welding2 droog_dun 180 |       | tijdlimiet | 9
-7  | wait welding                 |       | klaar      | 8
-7  | wait welding                 |       | tijdlimiet | 9
-8  | wait welding2                |       | klaar      | 10
-8  | wait welding2                |       | tijdlimiet | 9
-9  | output er is wat mis         | alarm |            | 0
-10 | output tweeling klaar        |       |            | 0
";

#[test]
fn a_second_welding_and_transport_station_from_their_stanzas_alone() {
    let mut rig = rig_grown(MORE, "20", |recipes| {
        copy_dir(&recipes.join("welding"), &recipes.join("welding2"));
        copy_dir(&recipes.join("transport"), &recipes.join("transport2"));
        std::fs::write(recipes.join("cell/tweeling.rcp"), TWEELING).expect("write");
    });
    // The operator delivered the new stations' recipes, named by station.
    rig.operator().expect_line(
        "EVENT delivered recipe=WELDING2$DROOG_DUN",
        Duration::from_secs(5),
    );
    let status = rig.status();
    for name in ["welding2", "transport2"] {
        assert!(
            status
                .stations
                .iter()
                .any(|s| s.name.as_str() == name && s.connected),
            "{name} not on the bus: {status:?}"
        );
    }

    rig.cell.falc(&["order", "add", "tweeling"]);
    rig.cell.falc(&["start"]);
    rig.work_list("ja", Duration::from_secs(120));
    let orders = rig.orders();
    assert_eq!(
        orders.last().map(|o| o.state),
        Some(OrderState::Done),
        "{orders:?}"
    );
    // Each robot ran its program: 65 (DROOG_DIK) and 66 (DROOG_DUN).
    rig.rcm.expect_line("rx G", Duration::from_secs(1));
    let (_, rcm2, _) = rig
        .more
        .iter_mut()
        .find(|(n, _, _)| n == "welding2")
        .expect("welding2's twin");
    rcm2.expect_line("rx G", Duration::from_secs(1));

    // The console reads the kinds from the topology too.
    let recipes = rig.recipes.display().to_string();
    let topology = rig.cell.topology_path.display().to_string();
    for cmd in ["check", "verify"] {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_falc"))
            .args(["--topology", &topology, "recipe", cmd, &recipes])
            .output()
            .expect("falc runs");
        assert!(out.status.success(), "falc recipe {cmd}: {out:?}");
    }
}
