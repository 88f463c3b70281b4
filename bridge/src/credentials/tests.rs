use super::*;

fn mk(file: &Path, user: Option<&str>, trust: Vec<PathBuf>) -> Result<()> {
    run(CredentialsOpts {
        file: file.to_owned(),
        user: user.map(str::to_owned),
        trust,
        forget: vec![],
        export: false,
    })
}

/// robot, ws1, ws2: each made on its own machine; cards exchanged as the README says.
fn lab(d: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let (robot, ws1, ws2) = (d.join("robot.cred"), d.join("ws1.cred"), d.join("ws2.cred"));
    mk(&robot, Some("robot"), vec![]).unwrap();
    mk(&ws1, Some("ws1"), vec![d.join("robot.pub")]).unwrap();
    mk(&ws2, Some("ws2"), vec![d.join("robot.pub")]).unwrap();
    mk(&robot, None, vec![d.join("ws1.pub"), d.join("ws2.pub")]).unwrap();
    (robot, ws1, ws2)
}

#[test]
fn both_ends_of_a_pair_derive_the_same_password_and_no_third_machine_can() {
    let d = tempfile::tempdir().unwrap();
    let (robot, ws1, ws2) = lab(d.path());
    let (r, w1, w2) = (
        Credentials::load(&robot).unwrap(),
        Credentials::load(&ws1).unwrap(),
        Credentials::load(&ws2).unwrap(),
    );
    let p = w1.pair_password("ws1", "robot").unwrap();
    assert_eq!(r.pair_password("ws1", "robot").unwrap(), p);
    assert_eq!(p.len(), 64);
    // Directional, and per pair.
    assert_ne!(w1.pair_password("robot", "ws1").unwrap(), p);
    assert_ne!(w2.pair_password("ws2", "robot").unwrap(), p);
    // ws2 is no party to ws1→robot: nothing to present as ws1, nor as robot.
    assert_eq!(w2.pair_password("ws1", "robot"), None);
    assert_eq!(w2.pair_password("robot", "ws1"), None);
    // The robot's dictionary: exactly its trusted identities with their pair passwords.
    let dict = r.zenoh_dictionary();
    assert_eq!(dict, format!("ws1:{p}\nws2:{}\n", w2.pair_password("ws2", "robot").unwrap()));
    // Nothing of the files themselves: no line of a credentials file or card is in it.
    for f in [&robot, &ws1, &ws2, &card_path(&robot)] {
        for line in std::fs::read_to_string(f).unwrap().lines() {
            assert!(!dict.lines().any(|l| l == line.trim()), "{line:?} reached the dictionary");
        }
    }
    // The cards hold no secret: the seed appears in no card.
    let seeds = r.secrets();
    for c in ["robot.pub", "ws1.pub", "ws2.pub"] {
        let card = std::fs::read_to_string(d.path().join(c)).unwrap();
        assert!(seeds.iter().all(|s| !card.contains(s.as_str())), "{c} holds a secret");
    }
}

#[test]
fn signatures_bind_key_and_payload_to_one_identity() {
    let d = tempfile::tempdir().unwrap();
    let (robot, ws1, _) = lab(d.path());
    let (r, w1) = (Credentials::load(&robot).unwrap(), Credentials::load(&ws1).unwrap());
    let sig = r.sign("bass/src/chunks", b"audio");
    let robot_id = w1.trusted("robot").unwrap();
    assert!(robot_id.verify("bass/src/chunks", b"audio", &sig));
    assert!(!robot_id.verify("bass/src/state", b"audio", &sig), "another key");
    assert!(!robot_id.verify("bass/src/chunks", b"audiO", &sig), "another payload");
    assert!(!robot_id.verify("bass/src/chunks", b"audio", &sig[..63]), "short");
    let forged = w1.sign("bass/src/chunks", b"audio");
    assert!(!robot_id.verify("bass/src/chunks", b"audio", &forged), "ws1 signs as robot");
    assert_eq!(r.signer().sign("bass/src/chunks", b"audio"), sig);
}

#[test]
fn old_comment_and_malformed_files_are_refused_by_name_without_content() {
    let e = format!(
        "{:#}",
        parse("# bass-bridge credentials: x\nrobot:0123456789abcdef0123\n", "f").unwrap_err()
    );
    assert!(e.contains("old shared-password credentials file") && !e.contains("0123456789"), "{e}");
    let e = format!("{:#}", parse("bass-bridge-credentials 2\nidentity robot\nseed zz\n", "f").unwrap_err());
    assert!(e.contains("f line 3") && e.contains("not 64 hex") && !e.contains("zz"), "{e}");
    let e = format!("{:#}", parse("bass-bridge-credentials 2\nidentity ro*bot\n", "f").unwrap_err());
    assert!(e.contains("f line 2") && e.contains("identity name"), "{e}");
    let e = format!("{:#}", parse("bass-bridge-credentials 2\nidentity robot\n", "f").unwrap_err());
    assert!(e.contains("no `identity` or no `seed`"), "{e}");
    let e = format!("{:#}", Identity::parse_card(&format!("{FILE_MAGIC}\nidentity x\n"), "c").unwrap_err());
    assert!(e.contains("is a private credentials file"), "{e}");
}

#[test]
fn files_are_made_and_changed_whole_as_ssh_treats_keys() {
    let d = tempfile::tempdir().unwrap();
    let (robot, ws1, _) = lab(d.path());
    assert_eq!(std::fs::metadata(&robot).unwrap().permissions().mode() & 0o777, 0o600);
    // Never overwritten by --user.
    assert!(mk(&robot, Some("robot"), vec![]).is_err());
    // Rotation: ws1 remade with new keys; --trust of its new card replaces the old keys.
    let old = Credentials::load(&robot).unwrap().trusted("ws1").unwrap().clone();
    std::fs::remove_file(&ws1).unwrap();
    mk(&ws1, Some("ws1"), vec![]).unwrap();
    mk(&robot, None, vec![d.path().join("ws1.pub")]).unwrap();
    let new = Credentials::load(&robot).unwrap().trusted("ws1").unwrap().clone();
    assert_ne!(old, new);
    assert_eq!(new, Credentials::load(&ws1).unwrap().identity());
    // A failed --trust (one good card, then a FIFO) leaves the file as it was.
    let before = std::fs::read(&robot).unwrap();
    let fifo = d.path().join("fifo.pub");
    assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    mk(&d.path().join("ws3.cred"), Some("ws3"), vec![]).unwrap();
    let e = format!("{:#}", mk(&robot, None, vec![d.path().join("ws3.pub"), fifo]).unwrap_err());
    assert!(e.contains("not a regular file"), "{e}");
    assert_eq!(std::fs::read(&robot).unwrap(), before);
    // Over 1 MiB: refused by size.
    let big = d.path().join("big.pub");
    std::fs::write(&big, vec![b'a'; (MAX_FILE + 1) as usize]).unwrap();
    let e = format!("{:#}", mk(&robot, None, vec![big]).unwrap_err());
    assert!(e.contains("more than the 1048576"), "{e}");
    assert_eq!(std::fs::read(&robot).unwrap(), before);
    // No temporary file left behind.
    let left: Vec<_> = std::fs::read_dir(d.path())
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
        .collect();
    assert!(left.is_empty(), "{left:?}");
    // A planted link at the card's path is replaced, not followed.
    let target = d.path().join("victim");
    std::fs::write(&target, "keep").unwrap();
    std::fs::remove_file(card_path(&robot)).unwrap();
    std::os::unix::fs::symlink(&target, card_path(&robot)).unwrap();
    run(CredentialsOpts { file: robot.clone(), user: None, trust: vec![], forget: vec![], export: true })
        .unwrap();
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "keep");
    // Readable by others: refused, naming the mode.
    std::fs::set_permissions(&ws1, std::fs::Permissions::from_mode(0o644)).unwrap();
    let e = Credentials::load(&ws1).unwrap_err().to_string();
    assert!(e.contains("mode 0644") && e.contains("chmod 600"), "{e}");
}
