//! The whole cell on a noisy robot line: the RCM twin flips one bit in 2 %
//! of the bytes on the DNC line, both ways, for the whole list. The 3964R
//! procedure repeats what noise spoils (an idle end answers a spoilt STX
//! with NAK), and the welding workstation takes only silence for a dead
//! line (`LinkEvent::Silent`; a request unanswered while bytes come gets
//! the link's own retry budget, `Timing::silent_after`), so no noise is
//! taken for a dead line: every order runs to done. (`cargo bench --bench
//! noise` reports 2 % and 5 %, and a dead line's detection time.)

use crate::support::noise::list_with_flips;
use crate::support::rig::rig;

#[test]
fn fifteen_dikdroog_orders_run_to_done_with_2_percent_bit_flips_on_the_robot_line() {
    // Scale 20: each weld takes 8.5 s, about eight status requests.
    let mut rig = rig("20");
    let run = list_with_flips(&mut rig, "2", 15);
    println!(
        "{} of {} orders done with 2 % bit flips ({} bytes flipped) in {:?}; alarms: {:#?}",
        run.done, run.orders, run.flipped, run.took, run.alarms
    );
    assert_eq!(run.done, run.orders, "alarms: {:#?}", run.alarms);
    assert!(run.alarms.is_empty(), "{:#?}", run.alarms);
    // The twin really spoilt bytes all along.
    assert!(run.flipped >= 20, "{} bytes flipped", run.flipped);
}
