//! The clock under arbitrary replies: it never panics, and system time never
//! goes backward except by a counted hard jump.

use osap_core::clock::{Clock, TimeConfig, TimeReply};
use osap_core::time::{Instant, SystemInstant};
use proptest::prelude::*;

#[derive(Debug, Clone)]
struct Exchange {
    link: usize,
    advance: u64,
    rtt: u64,
    echo_skew: i64,
    their_time: u64,
    tier: u8,
}

fn exchange() -> impl Strategy<Value = Exchange> {
    (
        0usize..3,
        0u64..200_000,
        0u64..5_000,
        prop_oneof![Just(0i64), -1_000_000i64..1_000_000],
        prop_oneof![any::<u64>(), 0u64..10_000_000],
        prop_oneof![Just(0u8), Just(1), any::<u8>()],
    )
        .prop_map(
            |(link, advance, rtt, echo_skew, their_time, tier)| Exchange {
                link,
                advance,
                rtt,
                echo_skew,
                their_time,
                tier,
            },
        )
}

proptest! {
    #[test]
    fn arbitrary_replies_never_panic_or_step_back_silently(
        exchanges in prop::collection::vec(exchange(), 1..200),
    ) {
        let mut clock: Clock<2> = Clock::new(TimeConfig::default());
        let mut local = 1_000u64;
        let mut last_system = clock.system_time(Instant::from_micros(local));
        let mut jumps = 0;
        for x in exchanges {
            local += x.advance;
            let _ = clock.due_requests(Instant::from_micros(local), 0b11);
            let sent = local.saturating_sub(x.rtt).saturating_add_signed(x.echo_skew);
            let reply = TimeReply {
                request_time: Instant::from_micros(sent),
                responder_time: SystemInstant::from_micros(x.their_time),
                responder_tier: x.tier,
            };
            // Link 2 does not exist on a Clock<2>: must be ignored.
            clock.on_reply(x.link, &reply, Instant::from_micros(local));
            let now = clock.system_time(Instant::from_micros(local));
            let status = clock.status();
            if status.stats.jumps == jumps {
                prop_assert!(now >= last_system, "went back {} µs without a jump", last_system - now);
            }
            jumps = status.stats.jumps;
            last_system = now;
            prop_assert!(status.rate_ppb.abs() <= 500_100);
        }
    }
}
