//! Tests that drive the crate as a whole through its own API: the endpoint
//! pair in simulated time on both storages, the first stamps of a base
//! written from `docs/wire.md`, the codec's and the regulator's properties,
//! and identification. The wire's test vectors and a policy written outside
//! the crate stay in `tests/`, as a user would see them.

mod endpoint_datagram;
mod endpoint_heap;
mod endpoint_inline;
mod first_stamp;
mod floor_sim;
mod identification_estimator;
mod identification_rls;
mod reconnect_sim;
mod regulator_props;
mod wire_props;
