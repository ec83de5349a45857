// rp2040js's ClockAlarm keeps `scheduled` true after it has fired, so it
// cannot tell "still pending" from "already ran". This wrapper can.

export function makeAlarm(clock, callback) {
  const a = {
    pending: false,
    schedule(deltaNanos) {
      a.pending = true;
      inner.schedule(Math.max(0, deltaNanos));
    },
    cancel() {
      a.pending = false;
      inner.cancel();
    },
  };
  const inner = clock.createAlarm(() => {
    a.pending = false;
    callback();
  });
  return a;
}
