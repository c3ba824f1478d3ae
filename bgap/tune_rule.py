from bgap.runner.numerics import command

main = command("bgap.commands.tune_rule")
if __name__ == "__main__":
    main()
