//! One call to the operator node as every command makes it: within
//! [`CALL_LIMIT`], the answer printed, or the refusal said with the exit
//! status it gives ([`crate::output::fail`]).

use crate::output::{fail, print};
use falc_bus::Bus;
use falc_model::api::ApiRequest;
use falc_model::ids::StationName;
use std::process::ExitCode;

pub use falc_bus::operator_service::CALL_LIMIT;

/// One call: printed, or the refusal on stderr.
pub(crate) async fn once(
    bus: &Bus,
    operator: &StationName,
    req: ApiRequest,
    json: bool,
) -> ExitCode {
    match bus.api(operator, req, CALL_LIMIT).await {
        Ok(reply) => {
            print(&reply, json);
            ExitCode::SUCCESS
        }
        Err(why) => fail(&why),
    }
}
