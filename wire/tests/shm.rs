//! `ShmTransport` between real processes. A test that needs another process runs this test
//! binary again with `--exact <test>` and an environment variable naming the part it plays
//! there (see [`helper`]); every test uses its own run id, so tests in parallel never meet.

use std::io::{BufRead, BufReader, Read};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use iceoryx2::prelude::{CallbackProgression, Config, MessagingPattern, Node, ServiceName, ipc};
use iceoryx2::service::Service;
use wire::{
    Control, Inbox, LargestMessages, Message, Outbox, Role, ShmLimits, ShmTransport, Topic,
    Transport, Weights,
};

const ROLE: &str = "PUSHGRASP_SHM_TEST_ROLE";
const RUN: &str = "PUSHGRASP_SHM_TEST_RUN";
const ARG: &str = "PUSHGRASP_SHM_TEST_ARG";
const READY: &str = "@@ready@@";
const PATIENCE: Duration = Duration::from_secs(30);
/// The tests' runs have a few processes each, and steps of up to 512 KiB (`numbered_len`).
const LIMITS: ShmLimits = ShmLimits::for_run(8, 512 * 1024);

fn unique_run(tag: &str) -> String {
    let nanos = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .subsec_nanos();
    format!("t-{tag}-{}-{nanos}", std::process::id())
}

/// The part this process plays: `None` in the test itself, `Some((role, run, arg))` in a
/// helper process.
fn helper_role() -> Option<(String, String, String)> {
    let role = std::env::var(ROLE).ok()?;
    let var = |name| std::env::var(name).unwrap_or_default();
    Some((role, var(RUN), var(ARG)))
}

/// A helper process: this test binary running test `test` as `role`. Killed if still running
/// when dropped.
struct Helper {
    child: Child,
    stdout: BufReader<ChildStdout>,
}

fn helper(test: &str, role: &str, run: &str, arg: &str) -> Helper {
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", test, "--nocapture", "--test-threads=1"])
        .env(ROLE, role)
        .env(RUN, run)
        .env(ARG, arg)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = BufReader::new(child.stdout.take().unwrap());
    Helper { child, stdout }
}

impl Helper {
    /// Waits until the helper says it is ready.
    fn wait_ready(&mut self) {
        let mut line = String::new();
        loop {
            line.clear();
            let n = self.stdout.read_line(&mut line).unwrap();
            assert!(n > 0, "the helper exited before it was ready");
            if line.contains(READY) {
                return;
            }
        }
    }

    /// Closes the helper's stdin (its signal to finish) and checks that it succeeded.
    fn finish(mut self) {
        drop(self.child.stdin.take());
        let status = self.child.wait().unwrap();
        assert!(status.success(), "helper failed: {status}");
    }

    fn kill(mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }
}

impl Drop for Helper {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// In a helper: says it is ready.
fn say_ready() {
    println!("{READY}");
}

/// In a helper: blocks until the test closes its stdin.
fn wait_for_stdin_to_close() {
    let _ = std::io::stdin().read_to_end(&mut Vec::new());
}

/// In a helper: a flag set when the test closes its stdin.
fn stdin_closed_flag() -> Arc<AtomicBool> {
    let flag = Arc::new(AtomicBool::new(false));
    let set = flag.clone();
    std::thread::spawn(move || {
        wait_for_stdin_to_close();
        set.store(true, Ordering::Release);
    });
    flag
}

/// Asserts that no node and no service of `run` is left.
fn assert_run_left_nothing(run: &str) {
    let config = Config::default();
    let prefix = format!("pushgrasp/{run}/");
    let mut nodes = Vec::new();
    Node::<ipc::Service>::list(&config, |state| {
        use iceoryx2::node::NodeView;
        let name = match &state {
            iceoryx2::prelude::NodeState::Alive(v) => {
                v.details().as_ref().map(|d| d.name().to_string())
            }
            iceoryx2::prelude::NodeState::Dead(v) => {
                v.details().as_ref().map(|d| d.name().to_string())
            }
            _ => None,
        };
        if let Some(name) = name.filter(|n| n.starts_with(&prefix)) {
            nodes.push(name);
        }
        CallbackProgression::Continue
    })
    .unwrap();
    assert!(nodes.is_empty(), "nodes of {run} left: {nodes:?}");
    for topic in Topic::ALL {
        let name = ServiceName::new(&format!("pushgrasp/{run}/{}", topic.name())).unwrap();
        let exists =
            ipc::Service::does_exist(&name, &config, MessagingPattern::PublishSubscribe).unwrap();
        assert!(!exists, "service {name} left");
    }
}

/// Polls `f` until it returns `Some`, for at most [`PATIENCE`].
fn poll<T>(what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(value) = f() {
            return value;
        }
        assert!(start.elapsed() < PATIENCE, "gave up waiting for {what}");
        std::thread::sleep(Duration::from_micros(200));
    }
}

// ---- Numbered messages: publisher index, sequence number, a checkable body.

fn numbered_len(seq: u64) -> usize {
    match seq % 10 {
        0 => 512 * 1024,
        1..=3 => 64 * 1024 + (seq % 1000) as usize,
        _ => 16 + (seq % 300) as usize,
    }
}

fn body_byte(publisher: u32, seq: u64, i: usize) -> u8 {
    (publisher as u64 * 31 + seq * 7 + i as u64) as u8
}

fn numbered(publisher: u32, seq: u64, out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(&publisher.to_le_bytes());
    out.extend_from_slice(&seq.to_le_bytes());
    let len = numbered_len(seq);
    out.extend((12..len).map(|i| body_byte(publisher, seq, i)));
}

/// Checks a numbered message: (publisher, seq).
fn check_numbered(bytes: &[u8]) -> (u32, u64) {
    let publisher = u32::from_le_bytes(bytes[..4].try_into().unwrap());
    let seq = u64::from_le_bytes(bytes[4..12].try_into().unwrap());
    assert_eq!(
        bytes.len(),
        numbered_len(seq),
        "publisher {publisher} seq {seq}"
    );
    let intact = (12..bytes.len()).all(|i| bytes[i] == body_byte(publisher, seq, i));
    assert!(intact, "publisher {publisher} seq {seq}: body corrupted");
    (publisher, seq)
}

/// In a helper: sends `count` numbered messages from publisher `index` on the steps topic.
fn send_numbered(run: &str, index: u32, count: u64) {
    let transport = ShmTransport::new(run, &format!("publisher-{index}"), LIMITS).unwrap();
    let mut publisher = transport.publisher(Topic::Steps).unwrap();
    let mut bytes = Vec::new();
    for seq in 0..count {
        numbered(index, seq, &mut bytes);
        publisher.send(&bytes).unwrap();
    }
}

#[test]
fn steps_from_two_processes_all_arrive_in_order_under_back_pressure() {
    const N: u64 = 2000;
    const TEST: &str = "steps_from_two_processes_all_arrive_in_order_under_back_pressure";
    if let Some((_, run, arg)) = helper_role() {
        send_numbered(&run, arg.parse().unwrap(), N);
        return;
    }
    let run = unique_run("steps");
    {
        let transport = ShmTransport::new(&run, "subscriber", LIMITS).unwrap();
        let mut subscriber = transport.subscriber(Topic::Steps).unwrap();
        let publishers = [
            helper(TEST, "publisher", &run, "0"),
            helper(TEST, "publisher", &run, "1"),
        ];
        // Both publishers fill the 32-message buffer and wait, before the subscriber first
        // looks (so before it has connected to them)...
        std::thread::sleep(Duration::from_millis(400));
        let mut next = [0u64; 2];
        let mut received = 0;
        let start = Instant::now();
        while next != [N, N] {
            let got = subscriber
                .receive(&mut |bytes| {
                    let (publisher, seq) = check_numbered(bytes);
                    assert_eq!(seq, next[publisher as usize], "publisher {publisher}");
                    next[publisher as usize] += 1;
                })
                .unwrap();
            if got {
                received += 1;
                if received == 100 {
                    // ... and after it has.
                    std::thread::sleep(Duration::from_millis(400));
                } else if received < 300 {
                    // A slow reader for a while.
                    std::thread::sleep(Duration::from_millis(1));
                }
            } else {
                assert!(start.elapsed() < PATIENCE, "stuck at {next:?}");
                std::thread::yield_now();
            }
        }
        for publisher in publishers {
            publisher.finish();
        }
        std::thread::sleep(Duration::from_millis(50));
        assert!(
            !subscriber
                .receive(&mut |_| panic!("an extra message"))
                .unwrap()
        );
    }
    assert_run_left_nothing(&run);
}

fn weights(version: u64) -> Message {
    Message::Weights(Weights {
        version,
        stage: 1,
        bytes: vec![version as u8; 100_000],
    })
}

#[test]
fn a_late_subscriber_gets_only_the_newest_weights() {
    const TEST: &str = "a_late_subscriber_gets_only_the_newest_weights";
    if let Some((_, run, _)) = helper_role() {
        let transport = ShmTransport::new(&run, "learner", LIMITS).unwrap();
        let mut outbox = Outbox::open(&transport, Topic::Weights).unwrap();
        for version in 1..=3 {
            outbox.send(&weights(version)).unwrap();
        }
        say_ready();
        // A publisher that stops sending hands its history to late subscribers when it
        // refreshes.
        let closed = stdin_closed_flag();
        while !closed.load(Ordering::Acquire) {
            outbox.refresh().unwrap();
            std::thread::sleep(Duration::from_millis(1));
        }
        return;
    }
    let run = unique_run("weights");
    {
        let mut learner = helper(TEST, "learner", &run, "");
        learner.wait_ready();
        let transport = ShmTransport::new(&run, "actor", LIMITS).unwrap();
        let mut inbox = Inbox::open(&transport, Topic::Weights).unwrap();
        let first = poll("the weights", || inbox.try_recv().unwrap());
        assert_eq!(first, weights(3));
        std::thread::sleep(Duration::from_millis(100));
        assert_eq!(inbox.drain().unwrap(), vec![]);
        learner.finish();
    }
    assert_run_left_nothing(&run);
}

#[test]
fn two_runs_stay_apart() {
    const TEST: &str = "two_runs_stay_apart";
    if let Some((_, run_a, run_b)) = helper_role() {
        let a = ShmTransport::new(&run_a, "launcher", LIMITS).unwrap();
        let b = ShmTransport::new(&run_b, "launcher", LIMITS).unwrap();
        let stop = |role| Message::Control(Control::Stop(role));
        // The outboxes stay until the test is done: what a publisher sent is lost if it is gone
        // before the subscriber first looks (see `wire::shm`).
        let mut outbox_a = Outbox::open(&a, Topic::Control).unwrap();
        let mut outbox_b = Outbox::open(&b, Topic::Control).unwrap();
        outbox_a.send(&stop(Role::Actor)).unwrap();
        outbox_b.send(&stop(Role::Learner)).unwrap();
        say_ready();
        wait_for_stdin_to_close();
        return;
    }
    let (run_a, run_b) = (unique_run("a"), unique_run("b"));
    {
        let a = ShmTransport::new(&run_a, "actor", LIMITS).unwrap();
        let b = ShmTransport::new(&run_b, "actor", LIMITS).unwrap();
        let mut inbox_a = Inbox::open(&a, Topic::Control).unwrap();
        let mut inbox_b = Inbox::open(&b, Topic::Control).unwrap();
        let mut launcher = helper(TEST, "launcher", &run_a, &run_b);
        launcher.wait_ready();
        let got_a = poll("run a's order", || inbox_a.try_recv().unwrap());
        let got_b = poll("run b's order", || inbox_b.try_recv().unwrap());
        assert_eq!(got_a, Message::Control(Control::Stop(Role::Actor)));
        assert_eq!(got_b, Message::Control(Control::Stop(Role::Learner)));
        std::thread::sleep(Duration::from_millis(50));
        assert_eq!(inbox_a.drain().unwrap(), vec![]);
        assert_eq!(inbox_b.drain().unwrap(), vec![]);
        launcher.finish();
    }
    assert_run_left_nothing(&run_a);
    assert_run_left_nothing(&run_b);
}

#[test]
fn another_protocol_version_is_refused_across_processes() {
    const TEST: &str = "another_protocol_version_is_refused_across_processes";
    if let Some((_, run, _)) = helper_role() {
        let transport = ShmTransport::new(&run, "old-actor", LIMITS).unwrap();
        let mut bytes = Vec::new();
        messages::codec::encode_with_version(&Message::Control(Control::Snapshot), 99, &mut bytes);
        let mut outbox = Outbox::open(&transport, Topic::Steps).unwrap();
        outbox.send_raw(&bytes).unwrap();
        say_ready();
        wait_for_stdin_to_close();
        return;
    }
    let run = unique_run("version");
    {
        let transport = ShmTransport::new(&run, "buffer", LIMITS).unwrap();
        let mut inbox = Inbox::open(&transport, Topic::Steps).unwrap();
        let mut actor = helper(TEST, "old-actor", &run, "");
        actor.wait_ready();
        let err = poll("the message", || inbox.try_recv().err());
        assert!(err.to_string().contains("protocol version 99"), "{err}");
        actor.finish();
    }
    assert_run_left_nothing(&run);
}

#[test]
fn what_a_killed_publisher_delivered_is_still_received() {
    const TEST: &str = "what_a_killed_publisher_delivered_is_still_received";
    let sent = sent_before_kill();
    if let Some((_, run, _)) = helper_role() {
        send_numbered_and_hang(&run);
        return;
    }
    let run = unique_run("killed-pub");
    {
        let transport = ShmTransport::new(&run, "buffer", LIMITS).unwrap();
        let mut subscriber = transport.subscriber(Topic::Steps).unwrap();
        let mut actor = helper(TEST, "actor", &run, "");
        let next = std::cell::Cell::new(0);
        let take = |subscriber: &mut Box<dyn wire::Subscriber>| {
            subscriber
                .receive(&mut |bytes| {
                    assert_eq!(check_numbered(bytes), (0, next.get()));
                    next.set(next.get() + 1);
                })
                .unwrap()
        };
        // The buffer reads the first messages while the actor lives...
        for _ in 0..5 {
            poll("a message", || take(&mut subscriber).then_some(()));
        }
        actor.wait_ready();
        actor.kill();
        let cleanup = ShmTransport::remove_stale(&run).unwrap();
        assert!(cleanup.removed <= 1, "{cleanup:?}");
        let again = ShmTransport::remove_stale(&run).unwrap();
        assert_eq!(again.removed, 0);
        assert_eq!(again.alive, vec![std::process::id() as i32]);
        // ... and the rest after it was killed and cleaned up.
        for _ in 5..sent {
            poll("a message of the killed actor", || {
                take(&mut subscriber).then_some(())
            });
        }
        assert!(!take(&mut subscriber));
        // A new process joins the run, and the buffer hears from it.
        let mut restarted = helper(TEST, "actor", &run, "");
        next.set(0);
        for _ in 0..sent {
            poll("a message of the restarted actor", || {
                take(&mut subscriber).then_some(())
            });
        }
        restarted.wait_ready();
        restarted.kill();
    }
    ShmTransport::remove_stale(&run).unwrap();
    assert_run_left_nothing(&run);
}

/// An actor that stops and exits before the buffer read any of its steps (the buffer was
/// holding them back for the learner): once the buffer has connected to it, they all arrive.
#[test]
fn steps_a_publisher_sent_before_it_exited_are_received_though_none_was_read_while_it_lived() {
    const TEST: &str =
        "steps_a_publisher_sent_before_it_exited_are_received_though_none_was_read_while_it_lived";
    let sent = Topic::Steps.buffer() as u64;
    if let Some((_, run, _)) = helper_role() {
        let transport = ShmTransport::new(&run, "actor", LIMITS).unwrap();
        let mut publisher = transport.publisher(Topic::Steps).unwrap();
        say_ready();
        wait_for_stdin_to_close();
        let mut bytes = Vec::new();
        for seq in 0..sent {
            numbered(0, seq, &mut bytes);
            publisher.send(&bytes).unwrap();
        }
        return;
    }
    let run = unique_run("exited-pub");
    {
        let transport = ShmTransport::new(&run, "buffer", LIMITS).unwrap();
        let mut subscriber = transport.subscriber(Topic::Steps).unwrap();
        let mut actor = helper(TEST, "actor", &run, "");
        actor.wait_ready();
        subscriber.refresh().unwrap();
        // The actor sends its steps, the largest first, and exits.
        actor.finish();
        for seq in 0..sent {
            let received = poll("a step of the exited actor", || {
                let mut got = None;
                subscriber
                    .receive(&mut |bytes| got = Some(check_numbered(bytes)))
                    .unwrap();
                got
            });
            assert_eq!(received, (0, seq));
        }
        assert!(!subscriber.receive(&mut |_| ()).unwrap());
    }
    assert_run_left_nothing(&run);
}

#[test]
fn a_step_larger_than_the_runs_largest_is_refused_with_both_sizes() {
    let run = unique_run("oversize");
    {
        let transport = ShmTransport::new(&run, "actor", LIMITS).unwrap();
        let _buffer = transport.subscriber(Topic::Steps).unwrap();
        let mut publisher = transport.publisher(Topic::Steps).unwrap();
        let largest = LIMITS.largest_step();
        publisher.send(&vec![1; largest]).unwrap();
        let err = publisher
            .send(&vec![1; largest + 1])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(&format!("{} bytes", largest + 1)) && err.contains(&largest.to_string()),
            "{err}"
        );
    }
    assert_run_left_nothing(&run);
}

/// What the killed publisher sends: the 5 the subscriber reads first, then a full buffer
/// that it has not read when the publisher dies.
fn sent_before_kill() -> u64 {
    5 + Topic::Steps.buffer() as u64
}

/// In a helper: sends [`sent_before_kill`] numbered messages, says it is ready, and waits
/// to be killed.
fn send_numbered_and_hang(run: &str) {
    let transport = ShmTransport::new(run, "actor", LIMITS).unwrap();
    let mut publisher = transport.publisher(Topic::Steps).unwrap();
    let mut bytes = Vec::new();
    for seq in 0..sent_before_kill() {
        numbered(0, seq, &mut bytes);
        publisher.send(&bytes).unwrap();
    }
    say_ready();
    wait_for_stdin_to_close();
    // The test kills this process; closing stdin instead is a failure.
    panic!("expected to be killed");
}

#[test]
fn a_publisher_waiting_on_a_killed_subscriber_goes_on_after_cleanup() {
    const TEST: &str = "a_publisher_waiting_on_a_killed_subscriber_goes_on_after_cleanup";
    if let Some((_, run, _)) = helper_role() {
        let transport = ShmTransport::new(&run, "buffer", LIMITS).unwrap();
        let _subscriber = transport.subscriber(Topic::Steps).unwrap();
        say_ready();
        wait_for_stdin_to_close();
        return;
    }
    let run = unique_run("killed-sub");
    {
        let mut buffer = helper(TEST, "buffer", &run, "");
        buffer.wait_ready();
        let transport = Arc::new(ShmTransport::new(&run, "actor", LIMITS).unwrap());
        let sent = Arc::new(AtomicUsize::new(0));
        let sender = {
            let (transport, sent) = (transport.clone(), sent.clone());
            std::thread::spawn(move || {
                let mut publisher = transport.publisher(Topic::Steps).unwrap();
                for _ in 0..Topic::Steps.buffer() + 8 {
                    publisher.send(&[7; 1000]).unwrap();
                    sent.fetch_add(1, Ordering::Release);
                }
            })
        };
        // The subscriber never reads: the publisher fills its buffer and waits.
        poll("a full buffer", || {
            (sent.load(Ordering::Acquire) == Topic::Steps.buffer()).then_some(())
        });
        std::thread::sleep(Duration::from_millis(200));
        assert_eq!(sent.load(Ordering::Acquire), Topic::Steps.buffer());
        buffer.kill();
        // A dead subscriber is noticed when it is cleaned up: here, or by any process that
        // creates an iceoryx2 node meanwhile (tests in parallel do).
        let cleanup = ShmTransport::remove_stale(&run).unwrap();
        assert!(cleanup.removed <= 1, "{cleanup:?}");
        poll("the publisher to go on", || {
            sender.is_finished().then_some(())
        });
        sender.join().unwrap();
    }
    assert_run_left_nothing(&run);
}

#[test]
fn a_dropped_subscriber_does_not_block_a_lossless_publisher() {
    let run = unique_run("dropped-sub");
    {
        let transport = ShmTransport::new(&run, "both", LIMITS).unwrap();
        let inbox = Inbox::open(&transport, Topic::Batches).unwrap();
        let mut outbox = Outbox::open(&transport, Topic::Batches).unwrap();
        let message = Message::Control(Control::Stop(Role::Learner));
        for _ in 0..Topic::Batches.buffer() {
            outbox.send(&message).unwrap();
        }
        drop(inbox);
        outbox.send(&message).unwrap();
    }
    assert_run_left_nothing(&run);
}

#[test]
fn bad_run_ids_are_refused_with_the_reason() {
    for bad in ["", "a/b", "run id", "../x"] {
        let err = ShmTransport::new(bad, "x", LIMITS).err().expect("refused");
        assert!(err.to_string().contains("run id"), "{err}");
    }
}

/// The names iceoryx2 gives the files of `run`'s nodes, ports and services (found while they
/// live): node ids, port ids (from the nodes' port tags), service hashes and service ids.
fn iceoryx2_names_of(run: &str) -> Vec<String> {
    let config = Config::default();
    let prefix = format!("pushgrasp/{run}/");
    let mut names = Vec::new();
    Node::<ipc::Service>::list(&config, |state| {
        use iceoryx2::node::NodeView;
        if let iceoryx2::prelude::NodeState::Alive(view) = &state
            && let Some(details) = view.details()
            && details.name().as_str().starts_with(&prefix)
        {
            names.push(view.id().value().to_string());
        }
        CallbackProgression::Continue
    })
    .unwrap();
    let node_dir = config.global.node_dir().to_string();
    for node in names.clone() {
        for entry in std::fs::read_dir(format!("{node_dir}/{node}")).unwrap() {
            let file = entry.unwrap().file_name().into_string().unwrap();
            let tagged = file.strip_prefix("iox2_").and_then(|f| f.split('.').next());
            names.extend(tagged.map(str::to_owned));
        }
    }
    names.retain(|name| name.len() >= 16);
    ipc::Service::list(&config, |service| {
        let details = &service.static_details;
        if details.name().as_str().starts_with(&prefix) {
            names.push(details.service_hash().as_str().to_owned());
            names.push(details.unique_service_id().value().to_string());
        }
        CallbackProgression::Continue
    })
    .unwrap();
    names
}

/// Every file under `dir`, recursively.
fn files_under(dir: &str) -> Vec<String> {
    let mut files = Vec::new();
    let mut dirs = vec![std::path::PathBuf::from(dir)];
    while let Some(dir) = dirs.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for entry in entries.flatten() {
            let path = entry.path();
            files.push(path.display().to_string());
            if path.is_dir() {
                dirs.push(path);
            }
        }
    }
    files
}

/// The files of iceoryx2 (shared memory and its directory) whose names hold one of `names`.
fn files_named(names: &[String]) -> Vec<String> {
    let mut files = files_under("/dev/shm");
    files.extend(files_under(
        &Config::default().global.root_path().to_string(),
    ));
    files.retain(|file| names.iter().any(|name| file.contains(name.as_str())));
    files
}

#[test]
fn a_run_leaves_no_files_behind_even_after_a_kill() {
    const TEST: &str = "a_run_leaves_no_files_behind_even_after_a_kill";
    if let Some((role, run, _)) = helper_role() {
        let transport = ShmTransport::new(&run, &role, LIMITS).unwrap();
        let mut steps = transport.publisher(Topic::Steps).unwrap();
        let mut weights = Outbox::open(&transport, Topic::Weights).unwrap();
        steps.send(&[1; 100_000]).unwrap();
        weights.send(&Message::Control(Control::Snapshot)).unwrap();
        say_ready();
        wait_for_stdin_to_close();
        return;
    }
    let run = unique_run("files");
    let names = {
        let transport = ShmTransport::new(&run, "buffer", LIMITS).unwrap();
        let mut steps = transport.subscriber(Topic::Steps).unwrap();
        let mut weights = Inbox::open(&transport, Topic::Weights).unwrap();
        let mut killed = helper(TEST, "killed", &run, "");
        let mut finished = helper(TEST, "finished", &run, "");
        killed.wait_ready();
        finished.wait_ready();
        let mut received = 0;
        poll("the steps", || {
            received += steps.receive(&mut |_| {}).unwrap() as usize;
            (received == 2).then_some(())
        });
        poll("the weights", || weights.try_recv().unwrap());
        let names = iceoryx2_names_of(&run);
        // Three nodes, their ports, two services: a file or more for each.
        let live = files_named(&names);
        assert!(live.len() >= 20, "{names:?} {live:#?}");
        killed.kill();
        finished.finish();
        ShmTransport::remove_stale(&run).unwrap();
        names
    };
    let left = files_named(&names);
    assert!(left.is_empty(), "files of run {run} left: {left:#?}");
    assert_run_left_nothing(&run);
}

/// In a helper process: joins its run as its role with a publisher of steps, says it is
/// ready and waits to be killed. Returns whether this process is such a helper.
fn publish_steps_until_killed() -> bool {
    let Some((role, run, _)) = helper_role() else {
        return false;
    };
    let transport = ShmTransport::new(&run, &role, LIMITS).unwrap();
    let _steps = transport.publisher(Topic::Steps).unwrap();
    say_ready();
    wait_for_stdin_to_close();
    true
}

#[test]
fn a_service_left_unsized_by_a_killed_process_is_removed() {
    const TEST: &str = "a_service_left_unsized_by_a_killed_process_is_removed";
    if publish_steps_until_killed() {
        return;
    }
    // A new process of another test may clean up after the killed one before this test
    // truncates its service: then the case did not arise, and it is set up again.
    let (run, dynamic) = (0..5)
        .find_map(|_| {
            let run = unique_run("unsized");
            let mut killed = helper(TEST, "killed", &run, "");
            killed.wait_ready();
            let dynamic: Vec<String> = files_named(&iceoryx2_names_of(&run))
                .into_iter()
                .filter(|file| file.starts_with("/dev/shm/") && file.ends_with(".dynamic"))
                .collect();
            assert_eq!(
                dynamic.len(),
                1,
                "the service's dynamic config: {dynamic:?}"
            );
            let dynamic = std::path::PathBuf::from(&dynamic[0]);
            killed.kill();
            // What a process killed between creating the service's dynamic config and sizing
            // it leaves behind: the shared memory at size zero.
            let file = std::fs::OpenOptions::new()
                .write(true)
                .open(&dynamic)
                .ok()?;
            file.set_len(0).unwrap();
            Some((run, dynamic))
        })
        .expect("five times, another process cleaned up before the service was truncated");
    // Cleaning up after the dead process (every new process does) must finish, removing the
    // service. Another test's new process may be the one that does it.
    let (done, cleaned) = std::sync::mpsc::channel();
    let (cleaning, file) = (run.clone(), dynamic.clone());
    std::thread::spawn(move || {
        poll("the unsized service's removal", || {
            ShmTransport::remove_stale(&cleaning).unwrap();
            (!file.exists()).then_some(())
        });
        let _ = done.send(());
    });
    cleaned
        .recv_timeout(PATIENCE)
        .expect("cleaning up after the killed process hung on the unsized service");
    assert_run_left_nothing(&run);
}

#[test]
fn a_node_killed_while_it_tagged_a_service_is_removed() {
    const TEST: &str = "a_node_killed_while_it_tagged_a_service_is_removed";
    if publish_steps_until_killed() {
        return;
    }
    let run = unique_run("tagging");
    let mut killed = helper(TEST, "killed", &run, "");
    killed.wait_ready();
    // The helper's node id, which its names list first.
    let node = iceoryx2_names_of(&run)[0].clone();
    let node_dir = std::path::Path::new(Config::default().global.node_dir().as_str()).join(&node);
    let tag = std::fs::read_dir(&node_dir)
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .find(|path| path.to_string_lossy().ends_with(".service_tag"))
        .expect("the node's tag of the service it publishes to");
    // What a process killed while it wrote the tag leaves: iceoryx2 makes a tag read-only
    // once written, and lists only those, so this one is never removed by its cleanup.
    std::fs::set_permissions(&tag, std::os::unix::fs::PermissionsExt::from_mode(0o600)).unwrap();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&tag)
        .unwrap()
        .set_len(0)
        .unwrap();
    killed.kill();
    // Another test's new process may be cleaning the dead node up meanwhile (and, unpatched,
    // stop at the tag after removing the node's details, so that no run can claim it).
    poll("the dead node's removal", || {
        ShmTransport::remove_stale(&run).unwrap();
        (!node_dir.exists()).then_some(())
    });
    assert_run_left_nothing(&run);
}

#[test]
fn a_node_killed_before_its_monitor_token_is_removed() {
    const TEST: &str = "a_node_killed_before_its_monitor_token_is_removed";
    if let Some((role, run, _)) = helper_role() {
        let _transport = ShmTransport::new(&run, &role, LIMITS).unwrap();
        say_ready();
        wait_for_stdin_to_close();
        return;
    }
    let run = unique_run("untokened");
    let mut killed = helper(TEST, "killed", &run, "");
    killed.wait_ready();
    let node = iceoryx2_names_of(&run)[0].clone();
    let config = Config::default();
    let nodes = std::path::PathBuf::from(config.global.node_dir().as_str());
    let node_dir = nodes.join(&node);
    // What a process killed after writing its node's details, before its monitor token was
    // made, leaves: the node's directory alone, which `Node::list` cannot find.
    let token = format!("iox2_{node}.");
    for file in std::fs::read_dir(&nodes)
        .unwrap()
        .map(|e| e.unwrap().path())
    {
        if file
            .file_name()
            .unwrap()
            .to_string_lossy()
            .starts_with(&token)
        {
            std::fs::remove_file(file).unwrap();
        }
    }
    // Alive, it may be making its token: left alone.
    ShmTransport::remove_stale(&run).unwrap();
    assert!(node_dir.exists(), "a live process's node was removed");
    killed.kill();
    let report = ShmTransport::remove_stale(&run).unwrap();
    assert!(!node_dir.exists(), "the dead node is left: {report:?}");
    assert_run_left_nothing(&run);
    assert_eq!(files_named(&[node]), Vec::<String>::new());
}

#[test]
fn a_node_directory_left_before_its_details_were_written_is_removed() {
    use std::os::unix::fs::PermissionsExt;
    // What a process killed between making its node's directory and writing the node's
    // details leaves: the directory, empty or with the details file half-written (empty,
    // read-write), which no listing finds.
    let nodes = std::path::PathBuf::from(Config::default().global.node_dir().as_str());
    std::fs::create_dir_all(&nodes).unwrap();
    let nanos = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_nanos();
    let [empty, half, fresh] = [1, 2, 3].map(|k| nodes.join(format!("{k}{nanos}")));
    let minutes_ago = SystemTime::now() - Duration::from_secs(180);
    let age = |path: &std::path::Path| {
        let file = std::fs::File::open(path).unwrap();
        file.set_modified(minutes_ago).unwrap();
    };
    for dir in [&empty, &half, &fresh] {
        std::fs::create_dir(dir).unwrap();
    }
    let details = half.join("iox2_node.details");
    std::fs::File::create(&details).unwrap();
    std::fs::set_permissions(&details, PermissionsExt::from_mode(0o600)).unwrap();
    for path in [&details, &half, &empty] {
        age(path);
    }
    ShmTransport::remove_stale(&unique_run("undetailed")).unwrap();
    assert!(
        !empty.exists(),
        "an empty node directory of 3 minutes ago is left"
    );
    assert!(
        !half.exists(),
        "a node directory with half-written details is left"
    );
    // One made just now may be getting its details.
    assert!(fresh.exists(), "a node directory made just now was removed");
    std::fs::remove_dir(fresh).unwrap();
}

#[test]
fn a_service_left_locked_by_a_killed_process_is_removed_and_its_run_resumes() {
    use std::os::unix::fs::PermissionsExt;
    let run = unique_run("locked");
    let config = Config::default();
    // The static config of the run's steps service, named by the service's hash.
    let static_config = {
        let transport = ShmTransport::new(&run, "buffer", LIMITS).unwrap();
        let _steps = transport.subscriber(Topic::Steps).unwrap();
        iceoryx2_names_of(&run)
            .into_iter()
            .find_map(|name| {
                let file = std::path::Path::new(config.global.service_dir().as_str())
                    .join(format!("iox2_{name}.service"));
                file.exists().then_some(file)
            })
            .expect("the steps service's static config")
    };
    assert!(!static_config.exists(), "the service outlived its process");
    // What a process killed between making the service's static config and writing it
    // leaves: the file empty and read-write, which says the service is being made. (Made
    // just now, other tests' cleanups leave it.)
    std::fs::File::create(&static_config).unwrap();
    std::fs::set_permissions(&static_config, PermissionsExt::from_mode(0o600)).unwrap();
    let resumed = ShmTransport::new(&run, "buffer", LIMITS).unwrap();
    assert!(
        resumed.subscriber(Topic::Steps).is_err(),
        "a service left locked was opened"
    );
    ShmTransport::remove_stale(&run).unwrap();
    assert!(
        static_config.exists(),
        "a service locked just now was removed"
    );
    let three_minutes_ago = SystemTime::now() - Duration::from_secs(180);
    std::fs::File::open(&static_config)
        .unwrap()
        .set_modified(three_minutes_ago)
        .unwrap();
    ShmTransport::remove_stale(&run).unwrap();
    assert!(
        !static_config.exists(),
        "a service locked 3 minutes ago is left"
    );
    resumed
        .subscriber(Topic::Steps)
        .expect("the run's service once its locked static config is gone");
}

#[test]
fn a_topic_admits_the_processes_of_its_run_and_names_the_limit_past_them() {
    let run = unique_run("limits");
    let limits = ShmLimits::for_run(40, 1000);
    // A process for each, as in a run: 80 nodes (each process, and a dead one's room).
    let transports: Vec<ShmTransport> = (0..81)
        .map(|i| ShmTransport::new(&run, &format!("role-{i}"), limits).unwrap())
        .collect();
    let mut orders = Vec::new();
    for transport in &transports[..80] {
        orders.push(transport.subscriber(Topic::Control).unwrap());
    }
    let err = transports[80]
        .subscriber(Topic::Control)
        .err()
        .expect("the 81st process is refused")
        .to_string();
    assert!(err.contains("a run of 40 processes"), "{err}");
}

/// The bytes of the run's shared-memory segments: as their files' sizes say (reserved), and
/// as their pages are (written).
fn segment_bytes(run: &str) -> (u64, u64) {
    use std::os::unix::fs::MetadataExt;
    let mut bytes = (0, 0);
    for file in files_named(&iceoryx2_names_of(run)) {
        if file.starts_with("/dev/shm/") && file.ends_with(".data") {
            let meta = std::fs::metadata(&file).unwrap();
            bytes.0 += meta.len();
            bytes.1 += meta.blocks() * 512;
        }
    }
    bytes
}

#[test]
fn a_runs_footprint_is_what_its_segments_reserve_and_bounds_what_they_hold() {
    let run = unique_run("footprint");
    let processes = 3;
    let limits = ShmLimits::for_run(processes, 100_000);
    let largest = LargestMessages {
        batch: 30_000,
        weights: 200_000,
    };
    let transports: Vec<ShmTransport> = (0..processes)
        .map(|i| ShmTransport::new(&run, &format!("p{i}"), limits).unwrap())
        .collect();
    // Every port the footprint counts: each process publishes steps and status and reads
    // weights and control; the first reads steps, status and requests, publishes weights,
    // control and batches; the second the other way round.
    let mut readers = Vec::new();
    for transport in &transports {
        readers.push(transport.subscriber(Topic::Weights).unwrap());
        readers.push(transport.subscriber(Topic::Control).unwrap());
    }
    for topic in [Topic::Steps, Topic::Status, Topic::Requests] {
        readers.push(transports[0].subscriber(topic).unwrap());
    }
    readers.push(transports[1].subscriber(Topic::Batches).unwrap());
    let mut sent = Vec::new();
    for transport in &transports {
        for topic in [Topic::Steps, Topic::Status] {
            let mut publisher = transport.publisher(topic).unwrap();
            publisher
                .send(&vec![1; largest_of(limits, &largest, topic)])
                .unwrap();
            sent.push(publisher);
        }
    }
    for (transport, topic) in [
        (&transports[0], Topic::Weights),
        (&transports[0], Topic::Control),
        (&transports[0], Topic::Batches),
        (&transports[1], Topic::Requests),
    ] {
        let mut publisher = transport.publisher(topic).unwrap();
        publisher
            .send(&vec![1; largest_of(limits, &largest, topic)])
            .unwrap();
        sent.push(publisher);
    }
    let footprint = limits.footprint(&largest);
    let (reserved, written) = segment_bytes(&run);
    // The segments' headers come on top (0.6% here).
    assert!(
        reserved >= footprint.reserved && reserved < footprint.reserved + footprint.reserved / 20,
        "{reserved} reserved against {footprint:?}"
    );
    assert!(
        written <= footprint.written,
        "{written} written against {footprint:?}"
    );
}

fn largest_of(limits: ShmLimits, largest: &LargestMessages, topic: Topic) -> usize {
    match topic {
        Topic::Steps => limits.largest_step(),
        Topic::Batches => largest.batch,
        Topic::Weights => largest.weights,
        _ => 1000,
    }
}
