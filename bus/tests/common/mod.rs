//! What the bus's integration tests share.

use cabc_proto::config::BusSection;

/// A bus section on a free loopback port: the learner listens where the others connect.
pub fn loopback() -> BusSection {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    BusSection {
        listen: vec![endpoint.clone()],
        connect: vec![endpoint],
        ..BusSection::default()
    }
}
